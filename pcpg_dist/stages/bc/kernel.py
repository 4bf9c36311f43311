"""A fused CPU kernel that trains many tiny MLP policies at once (the numba engine of Step C).

Why numba and not batched torch: for a 3x5 MLP ``torch.bmm`` over (cells, rows, 5) x (cells, 5, 5)
runs at ~0.2 GFLOP/s on CPU and per-op overhead dominates, while one compiled loop per cell keeps
its whole problem (a few hundred rows x a few widths) in L1 cache, vectorises over rows and
needs no padding. Cells are independent, so a cell's parameters do not depend on which other
cells share the call: training alone or in a batch is bit-for-bit the same.

Logs with many action ids and few legal at a time (:mod:`pcpg_dist.stages.legal_share`) take
the output layer at each row's legal actions only (:func:`_pairs_output`): row by row over its
pairs, the same loss and gradients as the dense softmax to float rounding
(``tests/stages/test_bc_legal_pairs.py``). It lives here, not in a module of its own, because
numba's cache of ``train_kernel`` is checked against this file only: a change to an inlined
function in another file would leave a stale kernel in the cache.

The maths is the torch engine's: weighted-mean masked cross-entropy, full batch, Adam exactly as
``torch.optim.Adam`` (no weight decay, no amsgrad). With ``batch > 0`` an epoch is instead one
pass over the cell's rows in consecutive blocks of ``batch`` rows (the caller shuffles the rows
once), one Adam step per block on the block's share of the loss scaled by rows / block rows. A
block is copied into the same contiguous buffers full batch uses, so every inner loop runs over
``range(rows)`` of a C-contiguous array and vectorises (loops over ``range(k0, k1)`` of the cell's
rows measured 5x slower).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_F = np.float32
_CLAMP = _F(7.90531110763549805)
_A = [_F(c) for c in (-2.76076847742355e-16, 2.00018790482477e-13, -8.60467152213735e-11,
    5.12229709037114e-08, 1.48572235717979e-05, 6.37261928875436e-04, 4.89352455891786e-03)]  # fmt: skip
_B = [_F(c) for c in (1.19825839466702e-06, 1.18534705686654e-04, 2.26843463243900e-03,
    4.89352518554385e-03)]  # fmt: skip
A0, A1, A2, A3, A4, A5, A6 = _A
B0, B1, B2, B3 = _B


@njit(inline="always", fastmath=True, error_model="numpy")
def tanh32(x):  # pragma: no cover - compiled
    """Eigen's rational tanh for float32 (max error ~4e-7): only +, *, / and clamps, so the
    loops that call it vectorise, where libm's tanh is a scalar call per element."""
    x = min(max(x, -_CLAMP), _CLAMP)
    x2 = x * x
    p = ((((((A0 * x2 + A1) * x2 + A2) * x2 + A3) * x2 + A4) * x2 + A5) * x2 + A6) * x
    q = ((B0 * x2 + B1) * x2 + B2) * x2 + B3
    return p / q


_FM = {"reassoc", "contract", "nsz"}


@njit(inline="always", fastmath=_FM, error_model="numpy")
def _load(xt, neg, acts, wn, start, rows, scale, h, negb, actb, wb):  # pragma: no cover - compiled
    """Copy ``rows`` rows from ``start`` into the block buffers (weights times ``scale``)."""
    for i in range(xt.shape[0]):
        for k in range(rows):
            h[0, i, k] = xt[i, start + k]
    for a in range(neg.shape[0]):
        for k in range(rows):
            negb[a, k] = neg[a, start + k]
    for k in range(rows):
        actb[k] = acts[start + k]
        wb[k] = wn[start + k] * scale


@njit(inline="always", fastmath=_FM, error_model="numpy")
def _forward(h, th, negb, sizes, w_off, b_off, rows, relu, upto):  # pragma: no cover - compiled
    """h[l+1] = act(W_l^T h[l] + b_l); h[L] = logits + mask, for the first ``rows`` columns and
    the first ``upto`` layers (all of them, or all but the output layer on the legal-pairs path)."""
    n_layers = len(sizes) - 1
    for layer in range(upto):
        fin = sizes[layer]
        fout = sizes[layer + 1]
        wo = w_off[layer]
        bo = b_off[layer]
        for j in range(fout):
            bj = th[bo + j]
            for k in range(rows):
                h[layer + 1, j, k] = bj
            for i in range(fin):
                w = th[wo + i * fout + j]
                for k in range(rows):
                    h[layer + 1, j, k] += w * h[layer, i, k]
            if layer < n_layers - 1:
                if relu:
                    for k in range(rows):
                        h[layer + 1, j, k] = max(h[layer + 1, j, k], np.float32(0.0))
                else:
                    for k in range(rows):
                        h[layer + 1, j, k] = tanh32(h[layer + 1, j, k])
            else:
                for k in range(rows):
                    h[layer + 1, j, k] += negb[j, k]


@njit(inline="always", fastmath=_FM, error_model="numpy")
def _softmax(lg, e, mx, tot, rows, n_actions):  # pragma: no cover - compiled
    """e = exp(logits - max) per row; mx the max, tot the sum."""
    for k in range(rows):
        mx[k] = lg[0, k]
    for a in range(1, n_actions):
        for k in range(rows):
            mx[k] = max(mx[k], lg[a, k])
    for k in range(rows):
        tot[k] = 0.0
    for a in range(n_actions):
        for k in range(rows):
            x = np.exp(lg[a, k] - mx[k])
            e[a, k] = x
            tot[k] += x


@njit(inline="always", fastmath=_FM, error_model="numpy")
def _output_grad(h, g, mx, tot, wb, actb, rows, n_actions, n_layers):  # pragma: no cover - compiled
    """g[0] = w * (softmax - onehot), from g[0] = exp(logits - max) and its sum ``tot``
    (:func:`_softmax`)."""
    for a in range(n_actions):
        for k in range(rows):
            g[0, a, k] = g[0, a, k] / tot[k] * wb[k]
    for k in range(rows):
        g[0, actb[k], k] -= wb[k]


@njit(inline="always", fastmath=_FM, error_model="numpy")
def _backward(h, g, th, grad, sizes, w_off, b_off, rows, relu, top):  # pragma: no cover - compiled
    """``grad`` of every weight and bias of layers ``top`` .. 0 from the gradient of layer
    ``top``'s output (before its activation) in g[0]; g[0] and g[1] take turns holding the
    gradient of the current layer's output."""
    cur = 0
    for layer in range(top, -1, -1):
        fin = sizes[layer]
        fout = sizes[layer + 1]
        wo = w_off[layer]
        bo = b_off[layer]
        for j in range(fout):
            acc = np.float32(0.0)
            for k in range(rows):
                acc += g[cur, j, k]
            grad[bo + j] = acc
        for i in range(fin):
            for j in range(fout):
                acc = np.float32(0.0)
                for k in range(rows):
                    acc += h[layer, i, k] * g[cur, j, k]
                grad[wo + i * fout + j] = acc
        if layer > 0:
            nxt = 1 - cur
            for i in range(fin):
                for k in range(rows):
                    g[nxt, i, k] = 0.0
                for j in range(fout):
                    w = th[wo + i * fout + j]
                    for k in range(rows):
                        g[nxt, i, k] += w * g[cur, j, k]
                if relu:
                    for k in range(rows):
                        if h[layer, i, k] <= 0.0:
                            g[nxt, i, k] = 0.0
                else:
                    for k in range(rows):
                        g[nxt, i, k] *= 1.0 - h[layer, i, k] * h[layer, i, k]
            cur = nxt


@njit(inline="always", fastmath=_FM, error_model="numpy")
def _adam(th, m, v, grad, n_params, step, lr, beta1, beta2, eps):  # pragma: no cover - compiled
    """One Adam step on ``th``, exactly as ``torch.optim.Adam`` (no weight decay, no amsgrad)."""
    bc1 = 1.0 - beta1**step
    bc2 = np.sqrt(1.0 - beta2**step)
    for p in range(n_params):
        m[p] = beta1 * m[p] + (1.0 - beta1) * grad[p]
        v[p] = beta2 * v[p] + (1.0 - beta2) * grad[p] * grad[p]
        th[p] -= lr / bc1 * m[p] / (np.sqrt(v[p]) / bc2 + eps)


@njit(inline="always", fastmath=_FM, error_model="numpy")
def _pair_row(
    hl, g, th, grad, sp, k, q0, q1, act, w, bo, want, back
):  # pragma: no cover - compiled
    """Row k's loss at its legal pairs q0:q1 (taken action ``act``, weight ``w``); with ``want``
    its share of the output layer's gradient (in gt and grad's biases) and of g[0]."""
    _, pair_act, wt, gt, lgq, hk = sp
    fin = wt.shape[1]
    for i in range(fin):
        hk[i] = hl[i, k]
    mx, taken = np.float32(-np.inf), np.float32(0.0)
    for q in range(q0, q1):
        a = pair_act[q]
        z = th[bo + a]
        for i in range(fin):
            z += wt[a, i] * hk[i]
        lgq[q - q0] = z
        mx = max(mx, z)
        if a == act:
            taken = z
    tot = np.float32(0.0)
    for q in range(q1 - q0):
        e = np.exp(lgq[q] - mx)
        lgq[q] = e
        tot += e
    if want:
        for q in range(q0, q1):
            a = pair_act[q]
            gq = w * lgq[q - q0] / tot - (w if a == act else np.float32(0.0))
            grad[bo + a] += gq
            for i in range(fin):
                gt[a, i] += gq * hk[i]
            if back:
                for i in range(fin):
                    g[0, i, k] += wt[a, i] * gq
    return -w * (taken - mx - np.log(tot))


@njit(inline="always", fastmath=_FM, error_model="numpy")
def _pairs_output(
    h, g, th, grad, sp, g0, rows, actb, wb, wo, bo, fout, want, relu
):  # pragma: no cover - compiled
    """The output layer at each row's legal actions only, on h[-1] (the last hidden layer's
    output, or the inputs): the rows' loss; with ``want`` the layer's gradient in ``grad`` and
    its input's (before its activation) in g[0]. ``sp`` = (pair_off, pair_act, wt, gt, lgq,
    hk): row g0 + k's legal actions (the taken one among them) are pair_act[pair_off[g0 + k]:
    pair_off[g0 + k + 1]]; wt / gt (actions, in) the weights and their gradient by action (a
    pair reads one contiguous run); lgq, hk a row's logits and inputs. Every sum runs in one
    fixed order (rows, then pairs): the same numbers whatever the thread count."""
    pair_off, _, wt, gt, _, _ = sp
    hl = h[len(h) - 1]
    fin, back = wt.shape[1], len(h) > 1  # back: a hidden layer below takes the gradient
    for i in range(fin):
        for a in range(fout):
            wt[a, i] = th[wo + i * fout + a]
    if want:
        gt[:, :] = 0.0
        for a in range(fout):
            grad[bo + a] = 0.0
        for i in range(fin if back else 0):
            for k in range(rows):
                g[0, i, k] = 0.0
    loss = 0.0
    for k in range(rows):
        q0, q1 = pair_off[g0 + k], pair_off[g0 + k + 1]
        loss += _pair_row(hl, g, th, grad, sp, k, q0, q1, actb[k], wb[k], bo, want, back)
    if want:
        for i in range(fin):
            for a in range(fout):
                grad[wo + i * fout + a] = gt[a, i]
        for i in range(fin if back else 0):  # through the last hidden layer's activation
            for k in range(rows):
                if relu:
                    if hl[i, k] <= 0.0:
                        g[0, i, k] = 0.0
                else:
                    g[0, i, k] *= 1.0 - hl[i, k] * hl[i, k]
    return loss


@njit(fastmath=_FM, nogil=True, error_model="numpy")  # called, not inlined: compiled once
def _block(
    h, g, th, grad, negb, mx, tot, wb, actb, rows, sizes, w_off, b_off, relu, sp, g0, want
):  # pragma: no cover - compiled
    """The loss of the rows in the buffers, or with ``want`` the gradient of every parameter in
    ``grad`` (dense softmax, or the legal pairs where ``sp`` holds them; the pairs' loss comes
    with their gradient)."""
    n_layers = len(sizes) - 1
    n_actions = sizes[n_layers]
    dense = len(sp[0]) == 0  # no pairs given: the dense softmax
    _forward(h, th, negb, sizes, w_off, b_off, rows, relu, n_layers if dense else n_layers - 1)
    if dense:
        lg = h[n_layers]
        _softmax(lg, g[0], mx, tot, rows, n_actions)
        loss = 0.0  # a training step needs the gradient only
        for k in range(0 if want else rows):
            loss -= wb[k] * (lg[actb[k], k] - mx[k] - np.log(tot[k]))
        if want:
            _output_grad(h, g, mx, tot, wb, actb, rows, n_actions, n_layers)
    else:
        wo, bo = w_off[n_layers - 1], b_off[n_layers - 1]
        loss = _pairs_output(
            h[:n_layers], g, th, grad, sp, g0, rows, actb, wb, wo, bo, n_actions, want, relu
        )
    if want:
        _backward(h, g, th, grad, sizes, w_off, b_off, rows, relu, n_layers - 1 - (not dense))
    return loss


@njit(inline="always", fastmath=_FM, error_model="numpy")
def _cell_loss(
    xt, neg, acts, wn, r0, n, nb, batch, h, g, negb, actb, wb, mx, tot, th, grad, sizes, w_off,
    b_off, relu, sp,
):  # pragma: no cover - compiled  # fmt: skip
    """The loss over the whole cell after training, block by block (full batch: the rows are
    already in the buffers)."""
    rows = n
    loss = 0.0
    for blk in range(nb):
        k0 = blk * batch if nb > 1 else 0
        if nb > 1:
            rows = min(n, k0 + batch) - k0
            _load(xt, neg, acts, wn, r0 + k0, rows, np.float32(1.0), h, negb, actb, wb)
        loss += _block(
            h, g, th, grad, negb, mx, tot, wb, actb, rows, sizes, w_off, b_off, relu, sp,
            r0 + k0, False,
        )  # fmt: skip
    return loss


@njit(inline="always", error_model="numpy")
def _pair_buffers(pair_off, pair_act, n_actions, fin):  # pragma: no cover - compiled
    """The ``sp`` tuple of :func:`_pairs_output` (its buffers empty on the dense path)."""
    most = 1
    for r in range(len(pair_off) - 1):
        most = max(most, pair_off[r + 1] - pair_off[r])
    by_action = n_actions if len(pair_off) > 0 else 0
    wt = np.empty((by_action, fin), np.float32)
    gt = np.empty((by_action, fin), np.float32)
    return pair_off, pair_act, wt, gt, np.empty(most, np.float32), np.empty(fin, np.float32)


@njit(cache=True, fastmath=_FM, nogil=True, error_model="numpy")
def train_kernel(
    xt, neg, acts, wn, row_off, theta, sizes, w_off, b_off, epochs, lr, beta1, beta2, eps, relu,
    cells, loss_out, batches, stop_window, stop_tol, steps_out, pair_off, pair_act,
):  # pragma: no cover - compiled  # fmt: skip
    """Train every cell in place.

    xt (d, R) normalised inputs; neg (A, R) 0 or -1e9 per action; acts (R,) targets; wn (R,)
    per-row weights summing to 1 within each cell; row_off (C+1,) cell row ranges; theta (C, P)
    parameters (updated in place); sizes (L+1,) layer widths; w_off/b_off (L,) offsets of each
    layer's (in, out) weights and (out,) bias in a row of theta. ``cells``: the cells this call
    trains, one after another. The kernel releases the GIL, so the caller runs one call per
    thread on disjoint cells (a ``prange`` ran as fast but took 25 s to compile on a fresh
    install, this 6 s). ``error_model="numpy"`` (a zero division gives inf, caught by the
    caller's finiteness check) lets the row loops vectorise (2x). ``batches[c]`` rows per Adam
    step of cell c (0: full batch) for ``epochs[c]`` passes; ``loss_out`` the loss over the whole
    cell after training, ``steps_out`` its Adam steps. Early stopping: every ``stop_window``
    steps (rounded up to whole epochs) a cell stops once its loss improved by less than
    ``stop_tol`` nats a row (``stop_window`` 0: all ``epochs``). Where ``pair_off`` (R+1,) is not
    empty, row r's legal actions are pair_act[pair_off[r]:pair_off[r + 1]], the output layer is
    computed at those only (:func:`_pairs_output`) and ``neg`` is (0, R).
    """
    n_layers = len(sizes) - 1
    sparse = len(pair_off) > 0
    maxw = 0
    for s in sizes[: n_layers if sparse else n_layers + 1]:
        maxw = max(maxw, s)
    n_actions = sizes[n_layers]
    n_params = theta.shape[1]
    sp = _pair_buffers(pair_off, pair_act, n_actions, sizes[n_layers - 1])
    for q in range(len(cells)):
        c = cells[q]
        batch = batches[c]
        r0 = row_off[c]
        n = row_off[c + 1] - r0
        nb = 1 if batch <= 0 or batch >= n else (n + batch - 1) // batch
        cap = n if nb == 1 else batch
        h = np.empty((n_layers + 1, maxw, cap), np.float32)
        g = np.empty((2, maxw, cap), np.float32)
        negb = np.empty((neg.shape[0], cap), np.float32)
        actb = np.empty(cap, np.int64)
        wb = np.empty(cap, np.float32)
        mx = np.empty(cap, np.float32)
        tot = np.empty(cap, np.float32)
        th = theta[c]
        m = np.zeros(n_params, np.float32)
        v = np.zeros(n_params, np.float32)
        grad = np.zeros(n_params, np.float32)
        rows = n
        every = 0 if stop_window <= 0 else ((stop_window + nb - 1) // nb) * nb
        last = np.inf
        if nb == 1:
            _load(xt, neg, acts, wn, r0, n, np.float32(1.0), h, negb, actb, wb)
        step = 0
        k0 = 0
        for step in range(1, epochs[c] * nb + 1):
            if nb > 1:
                # a block's weights scaled by n / rows: its gradient is an unbiased estimate
                # of the full-batch gradient (distinct rows keep their counts as weights, so
                # renormalising within a block would favour rare rows)
                k0 = ((step - 1) % nb) * batch
                rows = min(n, k0 + batch) - k0
                _load(xt, neg, acts, wn, r0 + k0, rows, np.float32(n / rows), h, negb, actb, wb)
            _block(
                h, g, th, grad, negb, mx, tot, wb, actb, rows, sizes, w_off, b_off, relu, sp,
                r0 + k0, True,
            )  # fmt: skip
            _adam(th, m, v, grad, n_params, step, lr, beta1, beta2, eps)
            if every > 0 and step % every == 0:
                now = _cell_loss(
                    xt, neg, acts, wn, r0, n, nb, batch, h, g, negb, actb, wb, mx, tot, th, grad,
                    sizes, w_off, b_off, relu, sp,
                )  # fmt: skip
                if last - now < stop_tol:
                    break
                last = now
        steps_out[c] = step
        loss_out[c] = _cell_loss(
            xt, neg, acts, wn, r0, n, nb, batch, h, g, negb, actb, wb, mx, tot, th, grad, sizes,
            w_off, b_off, relu, sp,
        )  # fmt: skip
