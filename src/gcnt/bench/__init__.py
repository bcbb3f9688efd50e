"""The benchmarks behind ``gcnt bench-train``, one module per algorithm."""
