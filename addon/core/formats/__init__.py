"""One module per splat file format, and `registry`, the table `splat_io` chooses among them
by; what several formats share lives beside it, in `formats_common`."""
