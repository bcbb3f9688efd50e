"""UNIMAL robots: the DERL symmetric design space, a generator, mutations, the checked-in set."""
