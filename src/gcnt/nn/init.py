"""Initial weights as the original codebases set them, one named scheme per family of methods.

Only the tensors the original code sets are touched; every other layer keeps PyTorch's default
(as in the originals):

* ``"amorpheus"`` (AMORPHEUS and SWAT, the SMPENV codebase GCNT was built on;
  ``yobibyte/amorpheus`` ``modular-rl/src/TransformerActor.py`` ``TransformerModel.init_weights``,
  the same in ``sunghoonhong/SWAT`` ``StructureActor.py``): the limb encoder's weight
  U(±0.1), the decoder's last layer weight U(±0.1) and bias 0.
* ``"metamorph"`` (MetaMorph, MetaMorph*, ModuMorph, the UNIMAL codebase GCNT was built on;
  ``agrimgupta92/metamorph`` and ``MasterXiong/ModuMorph`` ``metamorph/algos/ppo/model.py``
  ``TransformerModel.init_weights``): the limb embedding's weight U(±0.1), the decoder's last
  layer weight U(±0.01) and bias 0.
* ``"torch"``: PyTorch's defaults everywhere.

GCNT's own extra input, the fusion projection of [GCN ‖ WL] that is added to the limb embedding,
is initialised as the limb embedding (weight U(±0.1)): it is part of the token embedding. The GCN
layers keep PyTorch's defaults, as the originals' hidden layers do. Hypernetwork layers
(ModuMorph, GCNT+HN) have their own scheme (:class:`gcnt.nn.layers.HyperLinear`) and are not
touched here.
"""

from __future__ import annotations

from torch import nn

from gcnt.nn.layers import last_linear

#: scheme -> (embedding weight bound, decoder last-layer weight bound); the names are
#: :data:`gcnt.nn.config.INIT_SCHEMES`
SCHEMES: dict[str, tuple[float, float] | None] = {
    "amorpheus": (0.1, 0.1),
    "metamorph": (0.1, 0.01),
    "torch": None,
}


def init_like_original(
    scheme: str,
    *,
    embeddings: list[nn.Module] = (),  # type: ignore[assignment]
    decoder: nn.Module | None = None,
) -> None:
    """Set the weights of ``scheme`` (see :data:`SCHEMES`): the last Linear of each module of
    ``embeddings`` gets weight U(±embedding bound) (bias untouched); the last Linear of
    ``decoder`` gets weight U(±decoder bound) and bias 0."""
    if scheme not in SCHEMES:
        raise ValueError(f"unknown init scheme {scheme!r} (known: {', '.join(SCHEMES)})")
    bounds = SCHEMES[scheme]
    if bounds is None:
        return
    embed_bound, decoder_bound = bounds
    for module in embeddings:
        nn.init.uniform_(last_linear(module).weight, -embed_bound, embed_bound)
    if decoder is not None:
        out = last_linear(decoder)
        nn.init.uniform_(out.weight, -decoder_bound, decoder_bound)
        if out.bias is not None:
            nn.init.zeros_(out.bias)
