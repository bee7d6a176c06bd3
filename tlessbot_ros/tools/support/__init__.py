"""Code the `tlessbot` commands share; never a command itself."""
