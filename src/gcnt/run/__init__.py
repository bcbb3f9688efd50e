"""A run, as files: where it lives and how it is written (:mod:`~gcnt.run.directory`, with its
lock, :mod:`~gcnt.run.lock`, and its metrics file, :mod:`~gcnt.run.metrics`), what it records
about itself (the resolved record, :mod:`~gcnt.run.resolved`; stored robots and plugin
identities, :mod:`~gcnt.run.record`; the code and machine of each session,
:mod:`~gcnt.run.provenance`), and how the analysis commands read it back
(:mod:`~gcnt.run.data`).

This package sits below training (:mod:`gcnt.rl`) and analysis (:mod:`gcnt.analysis`): it
imports neither. Logging to W&B or CSV lives with the training loop
(:mod:`gcnt.rl.run_logger`).
"""
