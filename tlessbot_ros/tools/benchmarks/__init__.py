"""Benchmarks run by ``tlessbot bench <name>``; each module defines add_arguments() and run()."""
