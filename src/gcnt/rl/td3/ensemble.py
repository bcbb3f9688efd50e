"""Same-shaped networks as one module: parameters stacked, every member evaluated by one vmap.

TD3's twin critics (and its twin target critics) are two networks of one shape called on the same
inputs. :class:`Ensemble` holds one copy of the first member whose every parameter is replaced by
the members' parameters stacked along a new leading dimension ([N, ...]); a call runs the copy's
plain-tensor chain (:class:`~gcnt.rl.td3.tensor_chain.TensorChain`) once under ``torch.vmap`` over
that dimension, each member's slice swapped in for the call. Each operation of the network then
runs once for all members (one forward, one backward), and one optimiser, one gradient clip and
one soft update act on N times fewer, larger tensors. The robot table (the chain's buffers) is
not stacked: every member reads the same one.

Seeds stacked on top (:mod:`gcnt.rl.td3.stacked`) swap [N, ...] slices of their [S, N, ...]
leaves into the same module: the call reads whichever tensors are in place, so the members' vmap
runs inside the seeds' one.

The layout of a state dict is the copy's names with [N, ...] tensors; :func:`stack_members`
converts the members' own state dicts (``"0.<name>"``, ``"1.<name>"``, as an ``nn.ModuleList``
of the members writes them) into it.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence

import torch
from torch import Tensor, nn
from torch.nn.attention import SDPBackend, sdpa_kernel

from gcnt.rl.td3.tensor_chain import RobotBatch, TensorChain, has_dropout


#: the attention kernel under vmap: the math one (vmap's batching of the fused kernels takes no
#: gradient for a learnt additive mask such as GCNT's distance bias)
VMAP_SDPA = [SDPBackend.MATH]


class Ensemble(nn.Module):
    """``members`` (same-shaped TensorDict chains) as one module with stacked parameters.

    ``ensemble(inputs, robots, then)``: ``then`` (a function of a chain's output dict to a
    tensor, e.g. a member's loss) of every member's chain output on the same ``inputs``,
    stacked [N, ...] (members in the order given).
    """

    def __init__(self, members: Sequence[nn.Module]) -> None:
        super().__init__()
        if len(members) < 1:
            raise ValueError("Ensemble needs at least one member")
        self.size = len(members)
        self.net = copy.deepcopy(members[0])
        per_member = [dict(m.named_parameters()) for m in members]
        for name, p in list(self.net.named_parameters()):
            module_path, _, leaf = name.rpartition(".")
            owner = self.net.get_submodule(module_path)
            stacked = torch.stack([own[name].detach() for own in per_member])
            owner._parameters[leaf] = nn.Parameter(stacked, requires_grad=p.requires_grad)
        self.chain = TensorChain(self.net)
        # every (module, name) holding a parameter; copies of the ensemble copy these along
        # with the modules, and .to()/.double() keep the modules
        self._holders = [
            (m, n) for m in self.net.modules() for n, p in m._parameters.items() if p is not None
        ]
        # vmap draws each member's dropout mask on its own, as separate networks would
        self._randomness = "different" if has_dropout(self.net) else "error"

    def forward(
        self, inputs: Mapping, robots: RobotBatch, then: Callable[[dict], Tensor]
    ) -> Tensor:
        slots = self._holders
        # the tensors in place: the stacked parameters, or a stacked seed's slices of them
        stacked = [m._parameters[n] for m, n in slots]

        def member(params: list[Tensor]) -> Tensor:
            for (m, n), p in zip(slots, params, strict=True):
                m._parameters[n] = p
            try:
                return then(self.chain(inputs, robots))
            finally:
                for (m, n), p in zip(slots, stacked, strict=True):
                    m._parameters[n] = p

        with sdpa_kernel(VMAP_SDPA):
            return torch.vmap(member, randomness=self._randomness)(stacked)

    def one(self, i: int, inputs: Mapping, robots: RobotBatch, then: Callable[[dict], Tensor]):
        """``then`` of member ``i``'s chain output alone (its slice of every stacked parameter
        swapped in; no vmap): for a loss that reads one member, such as TD3's actor loss."""
        slots = self._holders
        stacked = [m._parameters[n] for m, n in slots]
        for (m, n), p in zip(slots, stacked, strict=True):
            m._parameters[n] = p[i]
        try:
            return then(self.chain(inputs, robots))
        finally:
            for (m, n), p in zip(slots, stacked, strict=True):
                m._parameters[n] = p

    def member(self, i: int) -> nn.Module:
        """Member ``i`` as a network of its own (a copy: for inspection and evaluation)."""
        out = copy.deepcopy(self.net)
        with torch.no_grad():
            for name, p in list(out.named_parameters()):
                module_path, _, leaf = name.rpartition(".")
                owner = out.get_submodule(module_path)
                owner._parameters[leaf] = nn.Parameter(p[i].clone(), requires_grad=p.requires_grad)
        return out


def is_members_layout(state: Mapping[str, Tensor]) -> bool:
    """Whether ``state`` is the members' own state dicts (``"0.<name>"``...), not stacked."""
    return bool(state) and all(k.split(".", 1)[0].isdigit() for k in state)


def stack_members(state: Mapping[str, Tensor], size: int) -> dict[str, Tensor]:
    """The members' state dicts (``"<i>.<name>"`` for i < ``size``) as an :class:`Ensemble`'s
    (``"net.<name>"`` [size, ...]); a ValueError when members are missing or differ in names."""
    per: list[dict[str, Tensor]] = [{} for _ in range(size)]
    for key, value in state.items():
        index, _, name = key.partition(".")
        if int(index) >= size:
            raise ValueError(f"{size} networks expected, the checkpoint holds {key}")
        per[int(index)][name] = value
    names = set(per[0])
    if any(set(p) != names for p in per):
        raise ValueError(f"the checkpoint's {size} networks do not hold the same tensors")
    return {f"net.{name}": torch.stack([p[name] for p in per]) for name in per[0]}
