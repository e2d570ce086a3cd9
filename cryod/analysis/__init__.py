"""What the simulation gets wrong on a measured record, its cause, the extended model and the gain.

Entry points: :func:`cryod.analysis.pipeline.analyze` (library) and
``cryod analyze`` (:mod:`cryod.cli.analyze`). The method is in
``docs/explanation/analysis-method.md``.
"""
