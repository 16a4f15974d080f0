"""Commands' work on files, end to end, without a console: read, process, write; typed results."""
