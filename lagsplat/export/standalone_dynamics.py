"""The identified latent dynamics, standalone: NumPy only (no lagsplat, no torch).

``python -m lagsplat export`` copies this file as ``export/dynamics.py`` beside ``weights.npz``; it implements
the Euler-Lagrange equation of the identified model (paper Eq. 7) with dissipation and measured actuation
(paper Eq. 6),

    ``M(q) qddot = dT/dq - (d(M qdot)/dq) qdot - dV/dq - C(q) qdot + f_ext + b(q)^T u``,

with ``T = 1/2 qdot^T M(q) qdot``, the Rayleigh dissipation ``D = 1/2 qdot^T C(q) qdot``, the potential
``V(q) = e^{s_V} (g(y) - g(y*) - grad g(y*)^T (y - y*) + eps/2 |y - y*|^2)``, ``y = phi(q)`` (``phi`` the
identity for the convex potential, an i-ResNet for the invex one; ``g`` an input-convex network),
``C(q) = e^{s_M} L_C(q) L_C(q)^T + c0 I`` and the inertia ``e^{s_M} I`` (``"scalar"``), a constant SPD matrix
(``"constant"``) or ``M(q) = e^{s_M} (L_M(q) L_M(q)^T + 0.1 I) / 1.1`` (``"learned"``).

Units: ``q`` in the whitened chart's units (``model.json``), time in seconds, ``qdot`` in chart units per
second. The state of :func:`rhs` is ``[q, qdot]`` (length ``2 d``).

Use::

    import numpy as np
    from scipy.integrate import solve_ivp
    import dynamics
    sol = solve_ivp(dynamics.rhs, (0.0, 10.0), np.concatenate([q0, qdot0]), rtol=1e-9, atol=1e-11)

:func:`rollout_verlet` repeats the velocity-Verlet scheme the project scores and plots with (paper Eq. 8).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["Model", "load", "rhs", "rollout_verlet"]

WEIGHTS = "weights.npz"
"""The weights' file name, looked up beside this file by :func:`load` without a path."""


def _softplus(x):
    """``log(1 + e^x)``, the identity above 20 (torch's threshold)."""
    return np.where(x > 20.0, x, np.log1p(np.exp(np.minimum(x, 20.0))))


def _softplus_slope(x):
    """Derivative of :func:`_softplus`: ``sigmoid(x)``, exactly 1 above 20."""
    return np.where(x > 20.0, 1.0, 1.0 / (1.0 + np.exp(-np.minimum(x, 20.0))))


def _elu(x):
    return np.where(x > 0.0, x, np.expm1(np.minimum(x, 0.0)))


def _elu_slope(x):
    return np.where(x > 0.0, 1.0, np.exp(np.minimum(x, 0.0)))


class Model:
    """The identified model, read from ``weights.npz`` (float64).

    Args:
        path: the weights file (default: ``weights.npz`` beside this module).

    Raises:
        FileNotFoundError: naming the file when it is missing.
        KeyError: when the file lacks an array this module needs.
    """

    def __init__(self, path: str | Path | None = None) -> None:
        path = Path(path) if path is not None else Path(__file__).resolve().parent / WEIGHTS
        if not path.exists():
            raise FileNotFoundError(f"{path}: weights file not found")
        with np.load(path, allow_pickle=False) as z:
            w = {k: z[k] for k in z.files}
        self.path = path
        self.d, self.n_u = int(w["d"]), int(w["n_u"])
        self.mass_kind = str(w["mass_kind"])
        self.M_const, self.M_inv = w["M"], w["M_inv"]
        self.exp_sV, self.exp_sM, self.c0, self.eps = (float(w[k]) for k in ("exp_sV", "exp_sM", "c0", "eps"))
        self.q_rest, self.y_rest, self.grad_rest = w["q_rest"], w["y_rest"], w["grad_rest"]
        self._icnn = self._icnn_layers(w["icnn_W"], w["icnn_b"], w["icnn_R"], w["icnn_out"], w["icnn_widths"])
        self._blocks = [(w["phi_W1"][k], w["phi_b1"][k], w["phi_W2"][k], w["phi_b2"][k]) for k in range(w["phi_W1"].shape[0])]
        self._diss = self._mlp_layers(w["diss_W"], w["diss_b"], w["diss_in"], w["diss_out"])
        self._mass = self._mlp_layers(w["mass_W"], w["mass_b"], w["mass_in"], w["mass_out"])
        self._act_a = w["act_a"]
        self._act = [self._icnn_layers(w["act_W"][j], w["act_b"][j], w["act_R"][j], w["act_out"][j], w["act_widths"]) for j in range(self.n_u)]
        self._tri = (w["tril_i"].astype(np.int64), w["tril_j"].astype(np.int64))
        self._g_rest = self._icnn_value(self._icnn, self.y_rest)

    # ------------------------------------------------------------------ layers
    @staticmethod
    def _icnn_layers(W, b, R, out, widths):
        """The ICNN's layers cut to their true widths: ``[(W_l, b_l, softplus(R_l))], softplus(w_out)``."""
        n = [int(v) for v in widths]
        layers = [(W[l, : n[l]], b[l, : n[l]], R[l, : n[l], : n[l - 1]] if l else None) for l in range(len(n))]
        return layers, out[: n[-1]]

    @staticmethod
    def _mlp_layers(W, b, n_in, n_out):
        """An ELU MLP's layers cut to their true sizes: ``[(W_k [out,in], b_k [out])]``."""
        return [(W[k, : int(n_out[k]), : int(n_in[k])], b[k, : int(n_out[k])]) for k in range(len(n_in))]

    @staticmethod
    def _icnn_pre(icnn, x):
        layers, _ = icnn
        pre = []
        for W, b, R in layers:
            s = W @ x + b
            if R is not None:
                s = s + R @ _softplus(pre[-1])
            pre.append(s)
        return pre

    def _icnn_value(self, icnn, x) -> float:
        """``g(x)``: ``h_1 = softplus(W_0 x + b_0)``, ``h_l = softplus(W_l x + R_l h_{l-1} + b_l)``, ``g = w_out^T h_L``."""
        return float(icnn[1] @ _softplus(self._icnn_pre(icnn, x)[-1]))

    def _icnn_grad(self, icnn, x):
        """``grad g(x) [d]`` by a backward pass through the layers."""
        layers, out = icnn
        pre = self._icnn_pre(icnn, x)
        delta = out * _softplus_slope(pre[-1])
        grad = layers[-1][0].T @ delta
        for l in range(len(layers) - 1, 0, -1):
            delta = (layers[l][2].T @ delta) * _softplus_slope(pre[l - 1])
            grad = grad + layers[l - 1][0].T @ delta
        return grad

    def _phi(self, q):
        """``(phi(q), pre-activations)`` through the i-ResNet blocks ``x + W_2 elu(W_1 x + b_1) + b_2``
        (``(q, [])`` for the convex potential)."""
        y, pre = np.array(q, dtype=np.float64), []
        for W1, b1, W2, b2 in self._blocks:
            pre.append(W1 @ y + b1)
            y = y + W2 @ _elu(pre[-1]) + b2
        return y, pre

    def _tril(self, raw):
        """Lower-triangular factor ``[d,d]`` from ``raw [d(d+1)/2]`` (softplus on the diagonal)."""
        i, j = self._tri
        L = np.zeros((self.d, self.d))
        L[i, j] = np.where(i == j, _softplus(raw), raw)
        return L

    def _mlp(self, layers, q, jacobian: bool = False):
        """The ELU MLP's output ``[m]`` at ``q`` and, with ``jacobian``, its Jacobian ``[m,d]`` (forward mode)."""
        x, J = np.array(q, dtype=np.float64), np.eye(self.d)
        for k, (W, b) in enumerate(layers):
            z = W @ x + b
            J = W @ J
            if k < len(layers) - 1:
                x, J = _elu(z), _elu_slope(z)[:, None] * J
            else:
                x = z
        return (x, J) if jacobian else x

    # ------------------------------------------------------------ the terms
    def potential(self, q) -> float:
        """Potential energy ``V(q)`` (paper Eq. 7), a float; ``q [d]``."""
        y = self._phi(q)[0]
        diff = y - self.y_rest
        return self.exp_sV * (self._icnn_value(self._icnn, y) - self._g_rest - diff @ self.grad_rest + 0.5 * self.eps * diff @ diff)

    def potential_grad(self, q):
        """``dV/dq [d]`` (closed form; pulled back through the i-ResNet for the invex potential)."""
        y, pre = self._phi(q)
        g = self._icnn_grad(self._icnn, y) - self.grad_rest + self.eps * (y - self.y_rest)
        for (W1, _, W2, _), p in zip(reversed(self._blocks), reversed(pre)):
            g = g + W1.T @ (_elu_slope(p) * (W2.T @ g))
        return self.exp_sV * g

    def dissipation_matrix(self, q):
        """Rayleigh matrix ``C(q) = e^{s_M} L_C L_C^T + c0 I [d,d]`` (``D = 1/2 qdot^T C qdot``)."""
        L = self._tril(self._mlp(self._diss, q))
        return self.exp_sM * (L @ L.T) + self.c0 * np.eye(self.d)

    def rayleigh(self, q, qdot) -> float:
        """Rayleigh dissipation function ``D = 1/2 qdot^T C(q) qdot`` (power dissipated: ``2 D``)."""
        v = np.asarray(qdot, np.float64)
        return 0.5 * float(v @ self.dissipation_matrix(q) @ v)

    def mass_matrix(self, q):
        """Inertia ``M(q) [d,d]``, SPD."""
        if self.mass_kind != "learned":
            return self.M_const.copy()
        L = self._tril(self._mlp(self._mass, q))
        return self.exp_sM * (L @ L.T + 0.1 * np.eye(self.d)) / 1.1

    def mass_matrix_and_derivative(self, q):
        """``(M [d,d], dM [d,d,d])`` of the learned inertia, ``dM[k] = dM/dq_k`` (forward mode through its MLP)."""
        raw, J = self._mlp(self._mass, q, jacobian=True)
        i, j = self._tri
        L = self._tril(raw)
        dL = np.zeros((self.d, self.d, self.d))
        dL[:, i, j] = (np.where(i == j, _softplus_slope(raw), 1.0)[:, None] * J).T
        LdLt = np.einsum("rm,kcm->krc", L, dL)
        s = self.exp_sM / 1.1
        return s * (L @ L.T + 0.1 * np.eye(self.d)), s * (LdLt + np.swapaxes(LdLt, 1, 2))

    def input_map(self, q):
        """``b(q) [n_u,d]``, the generalized force of the inputs ``f_P = b(q)^T u`` (paper Eq. 6); ``[0,d]`` without inputs."""
        rows = [self.exp_sV * (self._act_a[j] - self._icnn_grad(self._act[j], q)) for j in range(self.n_u)]
        return np.array(rows).reshape(self.n_u, self.d)

    def energy(self, q, qdot) -> float:
        """``E = T + V``, non-increasing along a free trajectory."""
        v = np.asarray(qdot, np.float64)
        return 0.5 * float(v @ self.mass_matrix(q) @ v) + self.potential(q)

    # ------------------------------------------------------------- dynamics
    def acceleration(self, q, qdot, u=None, f_ext=None):
        """``qddot [d]`` from the Euler-Lagrange equation (module docstring).

        Args:
            q, qdot: ``[d]`` state (chart units, per second).
            u: ``[n_u]`` inputs (e.g. pressures), or ``None`` (zero).
            f_ext: ``[d]`` generalized external force, or ``None``.

        Raises:
            ValueError: for inputs given to a model without input channels, or of the wrong length.
        """
        q, v = np.asarray(q, np.float64), np.asarray(qdot, np.float64)
        force = -self.potential_grad(q) - self.dissipation_matrix(q) @ v
        if f_ext is not None:
            force = force + np.asarray(f_ext, np.float64)
        if u is not None:
            u = np.asarray(u, np.float64).reshape(-1)
            if u.shape[0] != self.n_u:
                raise ValueError(f"u has {u.shape[0]} channels, the model {self.n_u}")
            if self.n_u:
                force = force + self.input_map(q).T @ u
        if self.mass_kind == "learned":
            M, dM = self.mass_matrix_and_derivative(q)
            w = dM @ v  # w[k] = dM_k v
            force = force + 0.5 * (w @ v) - w.T @ v
            return np.linalg.solve(M, force)
        return self.M_inv @ force

    def rhs(self, t: float, state, u=None, f_ext=None):
        """``d/dt [q, qdot] = [qdot, qddot]`` (paper Eq. 7) for ``scipy.integrate.solve_ivp`` (``state [2d]``, or
        ``[2d,k]`` vectorised; ``t`` in s).

        ``u``: ``None``, a constant ``[n_u]``, or a function ``t -> [n_u]`` (seconds); ``f_ext`` likewise ``[d]``.
        """
        s = np.asarray(state, np.float64)
        if s.ndim == 2:
            return np.stack([self.rhs(t, s[:, k], u, f_ext) for k in range(s.shape[1])], 1)
        q, v = s[: self.d], s[self.d :]
        u_t = u(t) if callable(u) else u
        f_t = f_ext(t) if callable(f_ext) else f_ext
        return np.concatenate([v, self.acceleration(q, v, u_t, f_t)])

    def rollout_verlet(self, q0, qdot0, h: float, n_states: int, u=None):
        """Velocity-Verlet rollout (paper Eq. 8), the project's scheme: ``a1 = a(q, v, u(t))``, ``v_h = v + h/2 a1``,
        ``q1 = q + h v_h``, ``a2 = a(q1, v_h, u(t + h))``, ``v1 = v_h + h/2 a2``.

        Args:
            q0, qdot0: ``[d]`` initial state; h: step in seconds; n_states: states returned, the first included.
            u: ``None``, a constant ``[n_u]`` or a function ``t -> [n_u]`` (``t = 0`` at ``q0``).

        Returns:
            ``(q [n_states,d], qdot [n_states,d])``; NaN from the step where the state stops being finite.
        """
        q, v = np.array(q0, np.float64), np.array(qdot0, np.float64)
        Q, V = np.full((n_states, self.d), np.nan), np.full((n_states, self.d), np.nan)
        Q[0], V[0] = q, v
        at = (lambda t: u(t)) if callable(u) else (lambda t: u)
        for i in range(1, n_states):
            t = (i - 1) * h
            vh = v + 0.5 * h * self.acceleration(q, v, at(t))
            q = q + h * vh
            v = vh + 0.5 * h * self.acceleration(q, vh, at(t + h))
            if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
                break
            Q[i], V[i] = q, v
        return Q, V


_DEFAULT: Model | None = None


def load(path: str | Path | None = None) -> Model:
    """The :class:`Model` of ``path`` (default ``weights.npz`` beside this file, read once and kept)."""
    global _DEFAULT
    if path is not None:
        return Model(path)
    if _DEFAULT is None:
        _DEFAULT = Model()
    return _DEFAULT


def rhs(t: float, state, u=None, f_ext=None):
    """``d/dt [q, qdot] = [qdot, qddot]`` of the default model, the Euler-Lagrange equation of paper Eq. 7
    (:meth:`Model.rhs`): ``solve_ivp(rhs, t_span, [q0, qdot0], args=(u,))``.

    Args:
        t: time, s (read only by a ``u`` or ``f_ext`` given as a function of time).
        state: ``[2d]`` (or ``[2d,k]`` for ``vectorized=True``): ``q`` in chart units, ``qdot`` in chart units per s.
        u: inputs ``[n_u]`` or ``t -> [n_u]`` (paper Eq. 6), ``None``: none; f_ext: generalized force ``[d]`` likewise.

    Raises:
        FileNotFoundError: if ``weights.npz`` is not beside this file (first call).
        ValueError: for inputs of the wrong length.
    """
    return load().rhs(t, state, u, f_ext)


def rollout_verlet(q0, qdot0, h: float, n_states: int, u=None):
    """:meth:`Model.rollout_verlet` of the default model."""
    return load().rollout_verlet(q0, qdot0, h, n_states, u)


if __name__ == "__main__":  # a smoke run: one second from a displaced rest state
    m = load()
    x0 = np.concatenate([m.q_rest + 0.1, np.zeros(m.d)])
    q, _ = m.rollout_verlet(x0[: m.d], x0[m.d :], 1e-3, 1001)
    print(f"d = {m.d}, inertia {m.mass_kind}, q(1 s) = {np.array2string(q[-1], precision=6)}, finite: {bool(math.isfinite(q[-1].sum()))}")
