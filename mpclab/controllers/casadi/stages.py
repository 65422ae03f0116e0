"""The stage structure of a multiple-shooting OCP, as a stage-wise QP solver (HPIPM) reads it.

HPIPM (through CasADi's ``conic``) takes a QP whose variables are ordered stage by stage,
``[x0 u0 x1 u1 ... xN uN]`` (states, then controls), and whose constraint rows are ordered
``[gap0 path0 gap1 path1 ... pathN]``: the rows that fix stage ``k + 1``'s states from stage
``k`` (the dynamics), then stage ``k``'s own rows, each on the variables of that stage only.
:func:`build_ocp` writes its variables in that order already: a stage's states are the
plant's ``x_k`` with the lifted input ``s_k``, its controls the soft constraints' slack and the
moves that start there. Its rows differ in one place: the initial-value rows
(``x_0 = x0``, ``s_0 = u_prev``) come before the first gap. :class:`StageLayout` reads each
row's stage off the Jacobian's pattern (a row that touches two stages closes a gap) and
gives the row order HPIPM needs.

One more difference: the slack of the last stage is a control of stage ``N``, where CasADi's
interface allows none. The layout appends an empty stage ``N + 1`` (no states, controls or
rows), so that stage ``N`` may have controls.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from mpclab.controllers.casadi.ocp import OCP


@dataclass(frozen=True)
class StageLayout:
    """Where each variable and row of an OCP sits in its stages.

    Attributes
    ----------
    nx, nu, ng
        States, controls and own (non-gap) rows of each stage, the empty last stage
        included (HPIPM's ``N + 1`` entries each).
    row_order
        The OCP's rows in HPIPM's order: ``qp_row[i] = ocp_row[row_order[i]]``.
    """

    nx: list[int]
    nu: list[int]
    ng: list[int]
    row_order: np.ndarray

    @property
    def horizon(self) -> int:
        """HPIPM's ``N`` (the OCP's horizon plus the empty stage)."""
        return len(self.nx) - 1

    def conic_options(self) -> dict[str, Any]:
        """The structure options of CasADi's ``hpipm`` conic."""
        return {"N": self.horizon, "nx": self.nx, "nu": self.nu, "ng": self.ng}

    @classmethod
    def of(cls, ocp: OCP, jacobian: ca.Sparsity) -> StageLayout:
        """The layout of a multiple-shooting ``ocp`` whose constraint Jacobian has the
        pattern ``jacobian``; a :class:`ValueError` names what does not fit the form."""
        if ocp.x_idx is None:
            raise ValueError("a stage-wise QP needs multiple shooting (states as variables)")
        n = ocp.lbw.size
        T = ocp.x_idx.shape[0] - 1
        stage = np.full(n, -1)
        state = np.zeros(n, dtype=bool)
        for k in range(T + 1):
            own = [ocp.x_idx[k]] + ([ocp.s_idx[k]] if ocp.s_idx is not None else [])
            for idx in own:
                stage[idx], state[idx] = k, True
            if ocp.slack_idx is not None and k > 0:
                stage[ocp.slack_idx[k - 1]] = k
        # a move belongs to the stage it is placed in: after that stage's states
        starts = ocp.x_idx[:, 0]
        for move in ocp.u_idx:
            stage[move] = int(np.searchsorted(starts, move[0], side="right") - 1)
        if (stage < 0).any() or (np.diff(stage) < 0).any():
            raise ValueError("the OCP's variables are not in stage order")
        for k in range(T + 1):  # within a stage: the states first, then the controls
            mine = np.flatnonzero(stage == k)
            if (np.diff(state[mine].astype(int)) > 0).any():
                raise ValueError(f"stage {k}: a control comes before a state")
        rows, cols = (np.asarray(a) for a in jacobian.get_triplet())
        m = jacobian.size1()
        first = np.full(m, T + 1)
        last = np.full(m, -1)
        np.minimum.at(first, rows, stage[cols])
        np.maximum.at(last, rows, stage[cols])
        if (last - first > 1).any():
            raise ValueError("a constraint row spans more than two stages")
        gap = last > first
        first[last < 0] = 0  # a row on no variable at all (constant): stage 0's
        order = np.argsort(2 * first + ~gap, kind="stable")
        nx = [int((state & (stage == k)).sum()) for k in range(T + 1)]
        gaps = [int((gap & (first == k)).sum()) for k in range(T + 1)]
        if gaps[:T] != nx[1:] or gaps[T]:
            raise ValueError(f"the dynamics rows per stage {gaps} do not fix the next "
                             f"stage's states {nx[1:]}")
        return cls(
            nx=[*nx, 0],
            nu=[int((~state & (stage == k)).sum()) for k in range(T + 1)] + [0],
            ng=[int((~gap & (first == k)).sum()) for k in range(T + 1)] + [0],
            row_order=order,
        )
