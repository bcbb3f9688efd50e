"""When a percentile bootstrap interval is reported: the one threshold shared by the run loop's
evaluation summary and the analysis commands (a module of its own, below both)."""

#: the fewest values a percentile bootstrap interval is reported (and named a CI) over; below it
#: the values' range is given and called so
MIN_BOOTSTRAP = 5
