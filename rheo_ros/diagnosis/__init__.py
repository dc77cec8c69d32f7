"""Model discovery: compare a model with the measurements, find what it misses."""
