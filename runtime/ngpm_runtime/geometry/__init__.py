"""Derivation and turtle geometry: one turtle semantics, one bounding box."""
