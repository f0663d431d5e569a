"""Infrastructure: files, errors, checksums, host memory and devices, locks, provenance."""
