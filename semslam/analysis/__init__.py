"""Analyses of a map that need no drive: predicted positioning accuracy (Hofmann) and
tag placement."""
