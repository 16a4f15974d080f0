"""The ``mdvae`` command line: thin click commands over the library."""
