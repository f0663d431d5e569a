"""Procedural motion synthesis: the two-hand corpus and the hand–object corpus (BimArt)."""
