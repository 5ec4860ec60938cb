"""One module per splat file format; `splat_io` chooses among them."""
