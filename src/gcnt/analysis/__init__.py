"""Reading run directories: sweeps over methods and seeds, curves, tables, embeddings, pictures.

Everything here works from run directories alone (``recipe.yaml``, ``metrics.jsonl``,
``checkpoints/last.pt``, ``eval/*.json``); W&B is never needed. Plotting and t-SNE libraries are
imported inside the functions that use them, so importing this package stays cheap.

* :mod:`gcnt.analysis.runs`: find runs, read their recipe, metrics and evaluations
* :mod:`gcnt.analysis.sweep`: expand a grid of recipes x methods x seeds and run it
* :mod:`gcnt.analysis.curves`: learning curves (paper figures 6, 7, 9)
* :mod:`gcnt.analysis.zeroshot`: zero-shot table (table 1)
* :mod:`gcnt.analysis.variants`: returns on robot variant sets with bootstrap CIs (figure 8)
* :mod:`gcnt.analysis.embed`: t-SNE of per-limb structural vectors (figure 10)
* :mod:`gcnt.analysis.strobe`: a strobe picture of one rollout (figure 11)
* :mod:`gcnt.analysis.tables`: parameter tables (tables 7-8)
"""
