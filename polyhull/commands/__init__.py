"""Sub-commands of the ``polyhull`` command line, one module each."""
