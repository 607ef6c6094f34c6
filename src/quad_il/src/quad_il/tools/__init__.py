"""Command-line tooling shared by the Makefile targets (test summary, benchmark output checks)."""
