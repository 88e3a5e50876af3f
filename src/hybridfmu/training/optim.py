"""Adam for the trainer (groups of parameters with their own learning rates): the update of ``torch.optim.Adam`` without ``torch.optim.Optimizer``.

Every method of ``torch.optim.Optimizer`` (constructor, ``step``, ``zero_grad``, ``state_dict``) imports
``torch._dynamo`` on first use, about 2 s of every training job's start-up; the job never compiles anything.
:class:`Adam` calls the same update function as ``torch.optim.Adam.step`` (``torch.optim.adam.adam``, the
single-tensor update on CPU) with the same arguments, so the parameters follow the same numbers bit for bit,
and its ``state_dict`` has the layout of ``torch.optim.Adam``'s (checkpoints load into either).
"""

from __future__ import annotations

from typing import Any, Iterable

import torch
from torch.optim.adam import adam as _adam_update

#: The hyperparameters of ``torch.optim.Adam``'s parameter group, with its defaults.
GROUP_DEFAULTS = {"eps": 1e-8, "weight_decay": 0, "amsgrad": False, "maximize": False, "foreach": None,
                  "capturable": False, "differentiable": False, "fused": None, "decoupled_weight_decay": False}


def _scalar_dtype() -> torch.dtype:
    return torch.float64 if torch.get_default_dtype() == torch.float64 else torch.float32


class Adam:
    """Adam over groups of parameters, as ``torch.optim.Adam(params, lr, betas)`` with its defaults.

    ``params`` is an iterable of tensors (one group) or of dicts ``{"params": [...], "lr": ...}`` (a group
    each; a group without ``"lr"`` uses ``lr``), as torch's optimizers take them.
    """

    def __init__(self, params: Iterable[Any], lr: float, betas: tuple[float, float]) -> None:
        items = list(params)
        if items and isinstance(items[0], dict):
            groups = [dict(item) for item in items]
        else:
            groups = [{"params": items}]
        self.param_groups: list[dict[str, Any]] = []
        self.params: list[torch.Tensor] = []
        for group in groups:
            members = list(group.pop("params"))
            unknown = [key for key in group if key != "lr"]
            if unknown:
                raise ValueError(f"Adam: parameter group options {unknown} are not supported (only 'lr')")
            self.param_groups.append({"lr": float(group.get("lr", lr)), "betas": tuple(betas), **GROUP_DEFAULTS,
                                      "_members": list(range(len(self.params), len(self.params) + len(members)))})
            self.params.extend(members)
        self.state: list[dict[str, torch.Tensor]] = [{} for _ in self.params]

    def zero_grad(self, set_to_none: bool = True) -> None:
        for p in self.params:
            if p.grad is None:
                continue
            if set_to_none:
                p.grad = None
            else:
                p.grad.detach_()
                p.grad.requires_grad_(False)
                p.grad.zero_()

    @torch.no_grad()
    def step(self) -> None:
        for group in self.param_groups:
            self._step_group(group)

    def _step_group(self, group: dict[str, Any]) -> None:
        params, grads, exp_avgs, exp_avg_sqs, steps = [], [], [], [], []
        has_complex = False
        for index in group["_members"]:
            p, state = self.params[index], self.state[index]
            if p.grad is None:
                continue
            has_complex |= torch.is_complex(p)
            if not state:
                state["step"] = torch.tensor(0.0, dtype=_scalar_dtype(), device="cpu")
                state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
            params.append(p)
            grads.append(p.grad)
            exp_avgs.append(state["exp_avg"])
            exp_avg_sqs.append(state["exp_avg_sq"])
            steps.append(state["step"])
        if not params:
            return
        beta1, beta2 = group["betas"]
        _adam_update(params, grads, exp_avgs, exp_avg_sqs, [], steps, amsgrad=group["amsgrad"],
                     has_complex=has_complex, beta1=beta1, beta2=beta2, lr=group["lr"],
                     weight_decay=group["weight_decay"], eps=group["eps"], maximize=group["maximize"],
                     foreach=group["foreach"], capturable=group["capturable"],
                     differentiable=group["differentiable"], fused=group["fused"], grad_scale=None,
                     found_inf=None, decoupled_weight_decay=group["decoupled_weight_decay"])

    def state_dict(self) -> dict[str, Any]:
        """``{"state": {index: {"step", "exp_avg", "exp_avg_sq"}}, "param_groups": [{..., "params": [indices]}]}``,
        the layout of ``torch.optim.Adam.state_dict()``."""
        groups = [{**{k: v for k, v in group.items() if k != "_members"}, "params": list(group["_members"])}
                  for group in self.param_groups]
        return {"state": {i: dict(state) for i, state in enumerate(self.state) if state}, "param_groups": groups}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Load a state written by :meth:`state_dict` or by ``torch.optim.Adam.state_dict()`` (same groups)."""
        groups = state_dict["param_groups"]
        if [len(g["params"]) for g in groups] != [len(g["_members"]) for g in self.param_groups]:
            raise ValueError(f"optimizer state: {len(groups)} parameter group(s) with "
                             f"{[len(g['params']) for g in groups]} parameters, expected "
                             f"{[len(g['_members']) for g in self.param_groups]}")
        saved = state_dict["state"]
        states: list[dict[str, torch.Tensor]] = [{} for _ in self.params]
        new_groups = []
        for mine, theirs in zip(self.param_groups, groups):
            for index, saved_index in zip(mine["_members"], theirs["params"]):
                p = self.params[index]
                state = {}
                for key, value in saved.get(saved_index, {}).items():
                    if key != "step" and torch.is_tensor(value) and p.is_floating_point():
                        value = value.to(dtype=p.dtype, device=p.device)
                    state[key] = value.clone() if torch.is_tensor(value) else value
                states[index] = state
            group = {key: value for key, value in theirs.items() if key != "params"}
            group["betas"] = tuple(group["betas"])
            new_groups.append({**GROUP_DEFAULTS, **group, "_members": list(mine["_members"])})
        self.state = states
        self.param_groups = new_groups
