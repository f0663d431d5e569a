"""Annotation: kinematic descriptors, segmentation into events, and captions from event records."""
