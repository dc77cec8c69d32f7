"""Reports of an analysis a person reads: ``html.write_report`` (``rheo analyze --report``)."""
