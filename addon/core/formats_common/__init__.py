"""What the splat file formats share: the error type and the memory bounds every reader checks,
the judge of paths inside files, generic containers (PLY, JSON, WebP), and the codecs several
formats use (codebooks, Morton order, quaternions as files store them, the RDF <-> RUB frame).
Nothing here is a format of its own; the formats are in `formats`."""
