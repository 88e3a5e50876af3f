"""Adam for the trainer: the update of ``torch.optim.Adam`` without ``torch.optim.Optimizer``.

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
    """Adam over one group of parameters (``torch.optim.Adam(params, lr, betas)`` with its defaults)."""

    def __init__(self, params: Iterable[torch.Tensor], lr: float, betas: tuple[float, float]) -> None:
        self.params = list(params)
        self.param_groups = [{"lr": lr, "betas": tuple(betas), **GROUP_DEFAULTS}]
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
        group = self.param_groups[0]
        params, grads, exp_avgs, exp_avg_sqs, steps = [], [], [], [], []
        has_complex = False
        for p, state in zip(self.params, self.state):
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
        return {"state": {i: dict(state) for i, state in enumerate(self.state) if state},
                "param_groups": [{**self.param_groups[0], "params": list(range(len(self.params)))}]}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Load a state written by :meth:`state_dict` or by ``torch.optim.Adam.state_dict()``."""
        groups = state_dict["param_groups"]
        if len(groups) != 1 or len(groups[0]["params"]) != len(self.params):
            raise ValueError(f"optimizer state: {len(groups)} parameter group(s) with "
                             f"{[len(g['params']) for g in groups]} parameters, expected one with {len(self.params)}")
        saved = state_dict["state"]
        states: list[dict[str, torch.Tensor]] = []
        for p, index in zip(self.params, groups[0]["params"]):
            state = {}
            for key, value in saved.get(index, {}).items():
                if key != "step" and torch.is_tensor(value) and p.is_floating_point():
                    value = value.to(dtype=p.dtype, device=p.device)
                state[key] = value.clone() if torch.is_tensor(value) else value
            states.append(state)
        self.state = states
        group = {key: value for key, value in groups[0].items() if key != "params"}
        group["betas"] = tuple(group["betas"])
        self.param_groups = [{**GROUP_DEFAULTS, **group}]
