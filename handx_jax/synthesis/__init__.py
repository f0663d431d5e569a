"""Procedural hands: motion programs, their kinematics and the contacts between hands."""
