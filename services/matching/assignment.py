"""Exact lexicographic assignments for the three steps (Eq. 4-7, 8-11, 13-16; docs/METHOD.md section 4).

Each step maximizes a primary objective over the matchings of a bipartite graph and, among the optimal
matchings, optimizes a secondary one: Step 1 the total sensing gain, then the total wait; Steps 2 and 3
the number of matches, then the total wait (Step 2) or the total phi (Step 3). Both objectives are kept
as separate whole numbers and compared in order, so no scaling or big-M weight mixes them and nothing
limits their size but int64: the solve is exact at every size the service accepts.

The solver is the shortest augmenting path method for rectangular assignment (Crouse 2016, the algorithm
behind ``scipy.optimize.linear_sum_assignment``), on a sparse graph and with pair-valued costs
``(-primary, +/-secondary)`` compared lexicographically (an ordered group, so the method's dual updates
hold unchanged). Every row also has a private "unmatched" column of cost (0, 0), so a row stays unmatched
unless matching it improves the objective; a pair is used only when it is given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from services.kernel.jit import compiled, compiled_inline

__all__ = ["Assignment", "lexicographic_assignment"]

_BIG = 2**62


@dataclass(frozen=True, slots=True)
class Assignment:
    """Matched pairs, as indices into the pairs given (``pair``) and as (row, col); the two totals."""

    pair: NDArray[np.int64]
    rows: NDArray[np.int64]
    cols: NDArray[np.int64]
    primary: int
    secondary: int


@compiled_inline
def _before(a1: int, b1: int, f1: int, a2: int, b2: int, f2: int) -> bool:
    if a1 != a2:
        return a1 < a2
    if b1 != b2:
        return b1 < b2
    return f1 < f2


@compiled_inline
def _up(
    ka: NDArray[np.int64],
    kb: NDArray[np.int64],
    kf: NDArray[np.int64],
    node: NDArray[np.int64],
    pos: NDArray[np.int64],
    i: int,
    a: int,
    b: int,
    f: int,
    j: int,
) -> None:
    while i > 0:
        p = (i - 1) >> 1
        if not _before(a, b, f, ka[p], kb[p], kf[p]):
            break
        ka[i] = ka[p]
        kb[i] = kb[p]
        kf[i] = kf[p]
        node[i] = node[p]
        pos[node[i]] = i
        i = p
    ka[i] = a
    kb[i] = b
    kf[i] = f
    node[i] = j
    pos[j] = i


@compiled_inline
def _down(
    ka: NDArray[np.int64],
    kb: NDArray[np.int64],
    kf: NDArray[np.int64],
    node: NDArray[np.int64],
    pos: NDArray[np.int64],
    size: int,
) -> None:
    """Sift the heap's entry at ``size`` (its last, once the root has been taken) down from the root."""
    la = ka[size]
    lb = kb[size]
    lf = kf[size]
    ln = node[size]
    h = 0
    while True:
        c = 2 * h + 1
        if c >= size:
            break
        if c + 1 < size and _before(ka[c + 1], kb[c + 1], kf[c + 1], ka[c], kb[c], kf[c]):
            c += 1
        if not _before(ka[c], kb[c], kf[c], la, lb, lf):
            break
        ka[h] = ka[c]
        kb[h] = kb[c]
        kf[h] = kf[c]
        node[h] = node[c]
        pos[node[h]] = h
        h = c
    ka[h] = la
    kb[h] = lb
    kf[h] = lf
    node[h] = ln
    pos[ln] = h


@compiled_inline
def _row_duals(
    u_a: NDArray[np.int64],
    u_b: NDArray[np.int64],
    sp_a: NDArray[np.int64],
    sp_b: NDArray[np.int64],
    col4row: NDArray[np.int64],
    sr_list: NDArray[np.int64],
    n_sr: int,
    cur: int,
    min_a: int,
    min_b: int,
) -> None:
    """The row duals after the search from row ``cur`` (the rows it scanned, in ``sr_list``)."""
    u_a[cur] += min_a
    u_b[cur] += min_b
    for t in range(n_sr):
        r = sr_list[t]
        if r != cur:
            jc = col4row[r]
            u_a[r] += min_a - sp_a[jc]
            u_b[r] += min_b - sp_b[jc]


@compiled_inline
def _col_duals(
    v_a: NDArray[np.int64],
    v_b: NDArray[np.int64],
    sp_a: NDArray[np.int64],
    sp_b: NDArray[np.int64],
    settled: NDArray[np.bool_],
    touched: NDArray[np.int64],
    n_touched: int,
    min_a: int,
    min_b: int,
) -> None:
    """The column duals of the columns the search settled."""
    for t in range(n_touched):
        jt = touched[t]
        if settled[jt]:
            v_a[jt] -= min_a - sp_a[jt]
            v_b[jt] -= min_b - sp_b[jt]


@compiled_inline
def _augment(
    path: NDArray[np.int64],
    path_pair: NDArray[np.int64],
    row4col: NDArray[np.int64],
    col4row: NDArray[np.int64],
    pair4row: NDArray[np.int64],
    sink: int,
    cur: int,
) -> None:
    """Augment along the shortest path from row ``cur`` to the free column ``sink``."""
    j = sink
    while True:
        r = path[j]
        row4col[j] = r
        prev = col4row[r]
        col4row[r] = j
        pair4row[r] = path_pair[j]
        j = prev
        if r == cur:
            break


@compiled_inline
def _reset(
    sp_a: NDArray[np.int64],
    sp_b: NDArray[np.int64],
    settled: NDArray[np.bool_],
    pos: NDArray[np.int64],
    touched: NDArray[np.int64],
    n_touched: int,
) -> None:
    """Leave the search's labels as the next row's search expects them."""
    for t in range(n_touched):
        jt = touched[t]
        sp_a[jt] = _BIG
        sp_b[jt] = 0
        settled[jt] = False
        pos[jt] = -1


@compiled_inline
def _heap(
    nc: int,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """An empty heap of labels ``(a, b, f)`` over ``nc`` columns: the entries' keys ``ka``, ``kb``, ``kf``
    and columns ``node``, and each column's entry ``pos`` (-1: not in the heap)."""
    ka = np.empty(nc, dtype=np.int64)
    kb = np.empty(nc, dtype=np.int64)
    kf = np.empty(nc, dtype=np.int64)
    node = np.empty(nc, dtype=np.int64)
    pos = np.full(nc, -1, dtype=np.int64)
    return ka, kb, kf, node, pos


@compiled
def _solve(
    n_rows: int,
    n_cols: int,
    indptr: NDArray[np.int64],
    col: NDArray[np.int64],
    ca: NDArray[np.int64],
    cb: NDArray[np.int64],
) -> NDArray[np.int64]:
    """Min-cost assignment of every row to a column or to its own dummy column ``n_cols + row`` (cost 0);
    costs ``(ca, cb)`` compared lexicographically. Returns the pair index chosen for each row, -1 for the
    dummy. ``indptr`` is the rows' CSR over the pairs."""
    nc = n_cols + n_rows
    u_a = np.zeros(n_rows, dtype=np.int64)
    u_b = np.zeros(n_rows, dtype=np.int64)
    v_a = np.zeros(nc, dtype=np.int64)
    v_b = np.zeros(nc, dtype=np.int64)
    col4row = np.full(n_rows, -1, dtype=np.int64)
    pair4row = np.full(n_rows, -1, dtype=np.int64)
    row4col = np.full(nc, -1, dtype=np.int64)
    sp_a = np.full(nc, _BIG, dtype=np.int64)
    sp_b = np.zeros(nc, dtype=np.int64)
    path = np.full(nc, -1, dtype=np.int64)
    path_pair = np.full(nc, -1, dtype=np.int64)
    settled = np.zeros(nc, dtype=np.bool_)
    touched = np.empty(nc, dtype=np.int64)
    sr_list = np.empty(n_rows, dtype=np.int64)
    ka, kb, kf, node, pos = _heap(nc)
    for cur in range(n_rows):
        n_touched = n_sr = size = min_a = min_b = 0  # the search from row cur starts with no label
        i = cur
        sink = -1
        while sink < 0:
            sr_list[n_sr] = i
            n_sr += 1
            # the row's pairs, then its dummy column
            for q in range(indptr[i], indptr[i + 1] + 1):
                if q < indptr[i + 1]:
                    j = col[q]
                    c_a = ca[q]
                    c_b = cb[q]
                else:
                    j = n_cols + i
                    c_a = 0
                    c_b = 0
                if settled[j]:
                    continue
                r_a = min_a + c_a - u_a[i] - v_a[j]
                r_b = min_b + c_b - u_b[i] - v_b[j]
                if r_a < sp_a[j] or (r_a == sp_a[j] and r_b < sp_b[j]):
                    if sp_a[j] == _BIG:
                        touched[n_touched] = j
                        n_touched += 1
                    sp_a[j] = r_a
                    sp_b[j] = r_b
                    path[j] = i
                    path_pair[j] = q if q < indptr[i + 1] else -1
                    f = 0 if row4col[j] < 0 else 1  # equal labels: a free column first
                    if pos[j] < 0:
                        _up(ka, kb, kf, node, pos, size, r_a, r_b, f, j)
                        size += 1
                    else:
                        _up(ka, kb, kf, node, pos, pos[j], r_a, r_b, f, j)
            # the lowest label
            j, min_a, min_b = node[0], ka[0], kb[0]
            pos[j] = -1
            size -= 1
            if size > 0:
                _down(ka, kb, kf, node, pos, size)
            settled[j] = True
            if row4col[j] < 0:
                sink = j
            else:
                i = row4col[j]
        _row_duals(u_a, u_b, sp_a, sp_b, col4row, sr_list, n_sr, cur, min_a, min_b)
        _col_duals(v_a, v_b, sp_a, sp_b, settled, touched, n_touched, min_a, min_b)
        _augment(path, path_pair, row4col, col4row, pair4row, sink, cur)
        _reset(sp_a, sp_b, settled, pos, touched, n_touched)
    return pair4row


def _compact(ids: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """``np.unique(ids, return_inverse=True)``: the distinct ids, ascending, and each one's index among
    them (by counting when the ids are small non-negative numbers, as indices are)."""
    lo, hi = int(ids.min()), int(ids.max())
    if lo < 0 or hi > 8 * ids.size + 1024:
        distinct, inverse = np.unique(ids, return_inverse=True)
        return distinct.astype(np.int64), inverse.astype(np.int64).ravel()
    present = np.bincount(ids, minlength=hi + 1) > 0
    rank = np.cumsum(present) - 1
    return np.flatnonzero(present).astype(np.int64), rank[ids].astype(np.int64)


def lexicographic_assignment(
    rows: NDArray[np.int64],
    cols: NDArray[np.int64],
    primary: NDArray[np.int64],
    secondary: NDArray[np.int64],
    *,
    secondary_sense: str,
) -> Assignment:
    """Among the matchings of the given pairs (``rows[k]``, ``cols[k]``), one that maximizes the total
    ``primary`` and, among those, minimizes (``secondary_sense="min"``) or maximizes (``"max"``) the total
    ``secondary``. Rows and columns may stay unmatched; a pair whose primary is 0 is used only when it
    improves the secondary (never with ``"min"`` and non-negative secondaries).

    Parameters
    ----------
    rows, cols : (k,) int
        The pairs (duplicates are not allowed).
    primary, secondary : (k,) int64
        Whole numbers; the totals of any matching must fit in int64 (the caller's units see to it).
    """
    if secondary_sense not in ("min", "max"):
        raise ValueError("secondary_sense must be 'min' or 'max'")
    rows = np.asarray(rows, dtype=np.int64)
    cols = np.asarray(cols, dtype=np.int64)
    primary = np.asarray(primary, dtype=np.int64)
    secondary = np.asarray(secondary, dtype=np.int64)
    empty = np.zeros(0, dtype=np.int64)
    if rows.size == 0:
        return Assignment(empty, empty, empty, 0, 0)
    # rows of the solve: the side with fewer distinct members (each is processed once)
    row_ids, row_idx = _compact(rows)
    col_ids, col_idx = _compact(cols)
    flip = col_ids.size < row_ids.size
    r_ids, r_idx, c_ids, c_idx = (
        (col_ids, col_idx, row_ids, row_idx) if flip else (row_ids, row_idx, col_ids, col_idx)
    )
    # the pairs by row, then column (keys are distinct: no duplicate pairs); a stable sort is linear on
    # pairs already in that order, as the pickups' are
    order = np.argsort(r_idx * c_ids.size + c_idx, kind="stable")
    indptr = np.zeros(r_ids.size + 1, dtype=np.int64)
    indptr[1:] = np.cumsum(np.bincount(r_idx, minlength=r_ids.size))
    sec = secondary if secondary_sense == "min" else -secondary
    chosen = _solve(
        int(r_ids.size), int(c_ids.size), indptr, c_idx[order].astype(np.int64), -primary[order], sec[order]
    )
    pairs = order[chosen[chosen >= 0]]
    pairs.sort()
    return Assignment(
        pairs,
        rows[pairs],
        cols[pairs],
        int(primary[pairs].sum()),
        int(secondary[pairs].sum()),
    )
