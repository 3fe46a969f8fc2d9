"""Scenes of several objects: ``plan`` (a plan's steps checked, torch-free: the service validates with it),
``describe`` (a description of several objects read into a plan, torch-free),
``assemble`` (a plan placed step by step, each step a run on the scene so far, every relation judged again on the
final scene with ``whole``) and ``copies`` (several of a kind,
arranged)."""
