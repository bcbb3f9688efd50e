"""Import gcnt before any test module imports torch, so the tests run with the OpenMP settings
``gcnt`` chooses (torch reads them once, when it loads)."""

import gcnt  # noqa: F401
