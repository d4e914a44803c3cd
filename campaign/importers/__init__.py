"""Importers of measurement series recorded by other software."""
