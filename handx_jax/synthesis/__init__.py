"""Procedural hands: motion synthesised from programs, the corpus build's source."""
