"""The `tlessbot` commands: one module (or package) per `tlessbot <command>`."""
