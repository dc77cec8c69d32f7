"""Configuration: the parameters table, the set-up built from it, node tuning."""
