"""Geometry in plain arrays and tensors: poses, frames, surface samples, distances."""
