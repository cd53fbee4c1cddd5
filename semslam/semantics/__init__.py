"""Semantics: class posteriors, connectivity constraints, the semantic map."""
