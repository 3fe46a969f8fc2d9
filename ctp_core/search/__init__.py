"""The search for where the source goes, before any gradient: ``proposals`` (poses in contact drawn from the
target's regions), ``coarse_to_fine`` (screened by the geometry, then ranked forward only by the guide at coarse
and finer views), ``scaling`` (scale mode's ladder and bounds) and ``ordering`` (which pose beats which, for every
stage: the one place that orders poses)."""
