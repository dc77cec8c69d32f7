"""Benchmarks: the paper reproduction and the estimators under noise."""
