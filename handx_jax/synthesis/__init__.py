"""Procedural hands: motion synthesised from programs (the two-hand corpus) and the hand–object corpus (BimArt)."""
