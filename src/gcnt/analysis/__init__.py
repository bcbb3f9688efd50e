"""Reading run directories: curves, tables, embeddings, pictures; and the paper's parameter counts.

Everything here works from run directories alone (``recipe.yaml``, ``metrics.jsonl``,
``checkpoints/last.pt``, ``eval/*.json``), the parameter counts from the networks alone; W&B is
never needed. Plotting and t-SNE libraries are
imported inside the functions that use them, so importing this package stays cheap.

* :mod:`gcnt.analysis.runs`: find runs, read their recipe, metrics and evaluations
* :mod:`gcnt.analysis.curves`: learning curves (paper figures 6, 7, 9)
* :mod:`gcnt.analysis.zeroshot`: zero-shot table (table 1)
* :mod:`gcnt.analysis.variants`: returns on robot variant sets with intervals over seeds (figure 8)
* :mod:`gcnt.analysis.embed`: t-SNE of per-limb structural vectors (figure 10)
* :mod:`gcnt.analysis.strobe`: a strobe picture of one rollout (figure 11)
* :mod:`gcnt.analysis.params`, :mod:`gcnt.analysis.tables`: parameter counts (tables 7-8)
* :mod:`gcnt.analysis.plotting`, :mod:`gcnt.analysis.names`, :mod:`gcnt.analysis.intervals`: how
  every figure is drawn and written (formats, size, fonts), what it calls methods and tasks, and
  how it names its intervals

Sweeps, which launch the training runs these modules read, are :mod:`gcnt.sweep`.
"""
