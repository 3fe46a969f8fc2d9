"""Geometry in plain arrays and tensors: poses (``pose``: translation, rotation, log scale), frames (``frames``: file,
normalised and source local, and the similarities between them), surface samples (``sampling``), nearest samples
(``nearest``), distance fields (``field``) and closest points (``proximity``)."""
