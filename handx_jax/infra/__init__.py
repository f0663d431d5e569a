"""Infrastructure: atomic files, readers, locks, host resources, provenance."""
