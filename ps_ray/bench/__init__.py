"""Benchmarks behind ``ps-ray bench <what>``: each prints figures, none is imported by the library."""
