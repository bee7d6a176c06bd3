"""Command-line tools, all behind one ``tlessbot`` executable (see :mod:`.cli`)."""
