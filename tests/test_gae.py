"""GAE with per-agent termination vs truncation against a plain-Python loop."""

import jax
import numpy as np

from jaxsmarl.gae import gae


def reference_gae(r, v, v_next, term, done, gamma, lam):
    T, E = r.shape
    adv = np.zeros((T, E))
    for e in range(E):
        a = 0.0
        for t in reversed(range(T)):
            if term[t, e]:
                delta, a = r[t, e] - v[t, e], 0.0
            else:
                delta = r[t, e] + gamma * v_next[t, e] - v[t, e]
                if done[t, e]:  # truncated: bootstrap from V(s'_t), new episode after
                    a = 0.0
            a = delta + gamma * lam * a
            adv[t, e] = a
    return adv, adv + v


def test_gae_matches_python_reference():
    rng = np.random.default_rng(0)
    T, E = 13, 7
    r, v, v_next = (rng.normal(size=(T, E)) for _ in range(3))
    term = rng.random((T, E)) < 0.15
    done = term | (rng.random((T, E)) < 0.15)  # some truncations without termination
    adv, ret = jax.jit(gae, static_argnums=(5, 6))(r.astype(np.float32), v.astype(np.float32),
                                                     v_next.astype(np.float32), term, done, 0.97, 0.9)
    adv_ref, ret_ref = reference_gae(r, v, v_next, term, done, 0.97, 0.9)
    np.testing.assert_allclose(adv, adv_ref, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ret, ret_ref, rtol=1e-5, atol=1e-5)


def test_truncation_bootstraps_termination_does_not():
    # One step, V(s') = 10: truncated -> r + gamma * 10 - V(s); terminated -> r - V(s).
    r, v, vn = np.array([[1.0, 1.0]]), np.array([[2.0, 2.0]]), np.array([[10.0, 10.0]])
    adv, _ = gae(r, v, vn, np.array([[False, True]]), np.array([[True, True]]), 0.9, 0.95)
    np.testing.assert_allclose(adv, [[1.0 + 9.0 - 2.0, 1.0 - 2.0]], rtol=1e-6)


def test_per_agent_termination_with_shared_done(x64):
    # [T, E, N]: agent 0 terminates at t=1 while the episode goes on; done broadcast from [T, E, 1].
    rng = np.random.default_rng(1)
    T, E, N = 6, 3, 2
    r, v, vn = (rng.normal(size=(T, E, N)) for _ in range(3))
    term = np.zeros((T, E, N), bool)
    term[1, :, 0] = True
    done = np.zeros((T, E), bool)
    done[3, :] = True
    adv, _ = gae(r, v, vn, term, done[:, :, None], 0.99, 0.95)
    for i in range(N):
        ref, _ = reference_gae(r[..., i], v[..., i], vn[..., i], term[..., i], done, 0.99, 0.95)
        np.testing.assert_allclose(adv[..., i], ref, rtol=1e-10)
