"""Benchmarks that reproduce and extend the papers' evaluations (``facetex bench ...``)."""
