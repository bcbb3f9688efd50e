"""Same-shaped networks as one module: parameters stacked, every member evaluated by one vmap.

TD3's twin critics (and its twin target critics) are two networks of one shape called on the same
inputs. :class:`Ensemble` holds one copy of the first member whose every parameter is replaced by
the members' parameters stacked along a new leading dimension ([N, ...]); a call runs the copy's
plain-tensor chain (:class:`~gcnt.rl.td3.tensor_chain.TensorChain`) once under ``torch.vmap`` over
that dimension, each member's slice swapped in for the call. Each operation of the network then
runs once for all members (one forward, one backward), and one optimiser, one gradient clip and
one soft update act on N times fewer, larger tensors. The robot table (the chain's buffers) is
not stacked: every member reads the same one.

:meth:`Ensemble.one` runs one member alone, without vmap, in a structural copy of the network
kept for that member: TD3 runs its two members that way on two threads on a CPU with a few cores
(where vmap's batched layers cost more arithmetic than two plain networks), each backpropagating
into its own slice of the stacked gradient, and reads critic 1 that way for the actor loss.

Seeds stacked on top (:mod:`gcnt.rl.td3.stacked`) swap [N, ...] slices of their [S, N, ...]
leaves into the same module: the call reads whichever tensors are in place, so the members' vmap
runs inside the seeds' one.

The layout of a state dict is the copy's names with [N, ...] tensors; :func:`stack_members`
converts the members' own state dicts (``"0.<name>"``, ``"1.<name>"``, as an ``nn.ModuleList``
of the members writes them) into it.
"""

from __future__ import annotations

import copy
import threading
from collections.abc import Callable, Mapping, Sequence

import torch
from torch import Tensor, nn
from torch.nn.attention import SDPBackend, sdpa_kernel

from gcnt.recipes import RecipeError
from gcnt.rl.td3.tensor_chain import RobotBatch, TensorChain, has_dropout

#: the attention kernel under vmap: the math one (vmap's batching of the fused kernels takes no
#: gradient for a learnt additive mask such as GCNT's distance bias)
VMAP_SDPA = [SDPBackend.MATH]


class VmapError(RecipeError):
    """A network that cannot be evaluated under ``torch.vmap`` (one line, exit 2)."""


class Ensemble(nn.Module):
    """``members`` (same-shaped TensorDict chains) as one module with stacked parameters.

    ``ensemble(inputs, robots, then)``: ``then`` (a function of a chain's output dict to a
    tensor, e.g. a member's loss) of every member's chain output on the same ``inputs``,
    stacked [N, ...] (members in the order given).
    """

    def __init__(self, members: Sequence[nn.Module], name: str = "network") -> None:
        super().__init__()
        self.name = name
        if len(members) < 1:
            raise ValueError("Ensemble needs at least one member")
        self.size = len(members)
        self.net = copy.deepcopy(members[0])
        per_member = [dict(m.named_parameters()) for m in members]
        for key, p in list(self.net.named_parameters()):
            module_path, _, leaf = key.rpartition(".")
            owner = self.net.get_submodule(module_path)
            stacked = torch.stack([own[key].detach() for own in per_member])
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

        try:
            with sdpa_kernel(VMAP_SDPA):
                return torch.vmap(member, randomness=self._randomness)(stacked)
        except RuntimeError as e:
            if not str(e).startswith("vmap:"):
                raise
            raise VmapError(
                f"{self.name}: its forward cannot run under torch.vmap, which evaluates TD3's "
                "twin critics as one ensemble (on a GPU, compiled, or with "
                f"compile.twin_threads=false): {str(e).split('. ')[0]}. Read no tensor's value "
                "in Python in the forward (.item(), int(), an if on a tensor), or on a CPU with "
                "2 to 4 cores run its members on threads (compile.twin_threads=true)"
            ) from None

    def one(
        self,
        i: int,
        inputs: Mapping,
        robots: RobotBatch,
        then: Callable[[dict], Tensor],
        fixed: bool = False,
        backward: bool = False,
    ) -> Tensor:
        """``then`` of member ``i``'s chain output alone (no vmap): its slice of every stacked
        parameter in a structural copy of the network kept for that member (sharing the
        network's buffers), so that two members can run at once on two threads. ``fixed``: the
        member is a constant function of its inputs (TD3's actor loss reads critic 1 and trains
        the actor only): its slices are detached, and kept from call to call while the stacked
        parameters are the same tensors (updated in place by the optimiser). ``backward``:
        backpropagate ``then``'s (scalar) result here, into member ``i``'s slice of the stacked
        gradient (:meth:`prepare_grads` first; the slice is replaced, once per optimiser step),
        and return it detached."""
        view, chain, slots = self._view(i)
        stacked = [m._parameters[n] for m, n in self._holders]
        leaves = None
        if fixed:
            params = self._fixed_slices(i, stacked)
        elif backward and self._into_grads(stacked):
            leaves, grad_slices = self._leaves(i, stacked)
            params = leaves
        else:
            params = [p[i] for p in stacked]
        before = [m._parameters[n] for m, n in slots]
        for (m, n), p in zip(slots, params, strict=True):
            m._parameters[n] = p
        try:
            out = then(chain(inputs, robots))
        finally:  # the view keeps no slice: under a seeds' vmap, a batched one
            for (m, n), p in zip(slots, before, strict=True):
                m._parameters[n] = p
        if not backward:
            return out
        out.backward()
        if leaves is not None:
            done = [
                (s, leaf.grad)
                for s, leaf in zip(grad_slices, leaves, strict=True)
                if leaf.grad is not None
            ]
            torch._foreach_copy_([s for s, _ in done], [g for _, g in done])
            for leaf in leaves:
                leaf.grad = None
        return out.detach()

    def views(self) -> None:
        """Build every member's structural copy now (:meth:`one` builds it at its first call
        otherwise): a compiled step that calls :meth:`one` must find it built, not trace the
        copying."""
        for i in range(self.size):
            self._view(i)
            views = self.__dict__["_views"]
            views.setdefault((i, "compiled"), views[(i, threading.get_ident())])

    def _view(self, i: int) -> tuple[nn.Module, TensorChain, list]:
        """Member ``i``'s structural copy for the calling thread: :meth:`one` swaps slices into
        it for the call, so two threads running the same member (TD3's actor loss over two
        halves of a batch) each need their own."""
        views = self.__dict__.get("_views")
        if views is None:
            views = self.__dict__["_views"] = {}
        # a compiled step runs on one thread, and cannot trace the thread's id
        key = (i, "compiled" if torch.compiler.is_compiling() else threading.get_ident())
        if key not in views:
            view = _structural_copy(self.net)
            # the holders in the copy, in the order of the network's
            where = {id(m): c for m, c in zip(self.net.modules(), view.modules(), strict=True)}
            slots = [(where[id(m)], n) for m, n in self._holders]
            views[key] = (view, TensorChain(view), slots)
        return views[key]

    def prepare_grads(self) -> None:
        """Give every stacked parameter a zero gradient before members backpropagate on threads
        (:meth:`one` with ``backward``): each member's gradients are then copied into its own
        slice of it, in one operator, with no select operators and no zero-filled [N, ...]
        gradient per member and parameter. Zero it in place after the optimiser step."""
        for m, n in self._holders:
            p = m._parameters[n]
            if p.requires_grad and p.grad is None:
                p.grad = torch.zeros_like(p)

    def _into_grads(self, stacked: list[Tensor]) -> bool:
        return (
            torch.is_grad_enabled()
            and not torch.compiler.is_compiling()
            and all(isinstance(p, nn.Parameter) and p.grad is not None for p in stacked)
        )

    def _leaves(self, i: int, stacked: list[Tensor]) -> tuple[list[Tensor], list[Tensor]]:
        """Member ``i``'s parameters as leaves of their own (detached slices that take a
        gradient), and its slices of the stacked gradients; kept while the parameters and their
        gradients are the same tensors."""
        cache = self.__dict__.setdefault("_leaf_cache", {})
        grads = [p.grad for p in stacked]
        hit = cache.get(i)
        if (
            hit is not None
            and all(a is b for a, b in zip(hit[0], stacked, strict=True))
            and all(a is b for a, b in zip(hit[1], grads, strict=True))
        ):
            return hit[2], hit[3]
        leaves = [p.detach()[i].requires_grad_() for p in stacked]
        slices = [g[i] for g in grads]
        cache[i] = (stacked, grads, leaves, slices)
        return leaves, slices

    def _fixed_slices(self, i: int, stacked: list[Tensor]) -> list[Tensor]:
        cache = self.__dict__.setdefault("_fixed", {})
        hit = cache.get(i)
        if hit is not None and all(a is b for a, b in zip(hit[0], stacked, strict=True)):
            return hit[1]
        slices = [p.detach()[i] for p in stacked]
        # plain parameters only: a stacked seed's batched slices are new at every call, and a
        # compiled step traces the slicing
        if not torch.compiler.is_compiling() and all(isinstance(p, nn.Parameter) for p in stacked):
            cache[i] = (stacked, slices)
        return slices

    def __getstate__(self) -> dict:  # copies build their own member views and slices
        state = dict(self.__dict__)
        state.pop("_views", None)
        state.pop("_fixed", None)
        state.pop("_leaf_cache", None)
        return state

    def member(self, i: int) -> nn.Module:
        """Member ``i`` as a network of its own (a copy: for inspection and evaluation)."""
        out = copy.deepcopy(self.net)
        with torch.no_grad():
            for name, p in list(out.named_parameters()):
                module_path, _, leaf = name.rpartition(".")
                owner = out.get_submodule(module_path)
                owner._parameters[leaf] = nn.Parameter(p[i].clone(), requires_grad=p.requires_grad)
        return out


def _structural_copy(module: nn.Module) -> nn.Module:
    """``module``'s tree of modules copied, each with its own parameter slots and submodules but
    the original's buffer dict (the robot table): a buffer the network swaps or moves, the copy
    reads too. Its parameter slots are filled by the caller before each call."""
    out = copy.copy(module)
    out._parameters = dict(module._parameters)
    out._modules = {
        k: None if m is None else _structural_copy(m) for k, m in module._modules.items()
    }
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
