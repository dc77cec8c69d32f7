"""I/O: message conversion and bags. The only place that knows message layouts."""
