"""Unit tests of the one-material-point constitutive models (parsph.solid).

Hencky elasticity against closed forms and scipy's matrix logarithm, objectivity under
large rigid rotations; Drucker-Prager return map (yield surface hit, consistency, apex,
softening to the residual cohesion, non-associative flow); modified Cam-Clay (Newton
convergence, drained triaxial stress path and critical state for the Table 1 soil,
p' -> 0). Stresses are tension positive outside the soil modules.
"""
import math

import numpy as np
import pytest
from scipy.linalg import expm, logm
from scipy.optimize import brentq

from parsph.solid import cam_clay as mcc
from parsph.solid import drucker_prager as dp
from parsph.solid import hencky
from parsph.core import tensor

RNG_SEED = 20240601


def rotation(axis, angle):
    """Rotation matrix about ``axis`` by ``angle`` (rad), Rodrigues' formula."""
    n = np.asarray(axis, dtype=float)
    n = n / np.linalg.norm(n)
    W = np.array([[0.0, -n[2], n[1]], [n[2], 0.0, -n[0]], [-n[1], n[0], 0.0]])
    return np.eye(3) + math.sin(angle) * W + (1.0 - math.cos(angle)) * W @ W


def random_sym(rng, spectrum):
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    A = Q @ np.diag(spectrum) @ Q.T
    return 0.5 * (A + A.T)


def dev_q(tau):
    s = tau - np.trace(tau) / 3.0 * np.eye(3)
    return s, math.sqrt(1.5 * np.sum(s * s))


# --------------------------------------------------------------------------- tensor


@pytest.mark.parametrize("kind", ["distinct", "double", "near_double", "near_identity", "triple"])
def test_eigh3_matches_numpy_and_is_orthonormal(kind):
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(300):
        a, b = rng.normal(size=2)
        spectrum = {
            "distinct": rng.normal(size=3),
            "double": np.array([a, a, b]),
            "near_double": np.array([a, a * (1 + 1e-9), b]),
            "near_identity": 1.0 + 1e-9 * rng.normal(size=3),
            "triple": np.array([a, a, a]),
        }[kind]
        A = random_sym(rng, spectrum)
        w, V = tensor.eigh3(A)
        scale = np.abs(A).max()
        assert np.allclose(w, np.linalg.eigvalsh(A), rtol=0, atol=1e-13 * scale)
        assert np.allclose(V.T @ V, np.eye(3), atol=1e-13)
        assert np.abs(A @ V - V * w).max() <= 1e-13 * scale


def test_jacobi_fallback_agrees_and_nan_does_not_hang():
    rng = np.random.default_rng(RNG_SEED)
    A = random_sym(rng, [3.0, -1.0, -1.0])
    w1, _ = tensor.eigh3(A)
    w2, V2 = tensor.eigh3_jacobi(A)
    assert np.allclose(w1, w2, atol=1e-13)
    assert np.allclose(A @ V2, V2 * w2, atol=1e-13)
    w, _ = tensor.eigh3(np.full((3, 3), np.nan))
    assert np.isnan(w).all()


def test_log_exp_det_inv():
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(50):
        A = random_sym(rng, np.exp(rng.normal(size=3)))
        L = tensor.logm_spd(A)
        assert np.allclose(L, logm(A).real, atol=1e-12)
        assert np.allclose(tensor.expm_sym(L), A, rtol=1e-12, atol=1e-12)
        assert np.allclose(tensor.expm_sym(L, 2.0), expm(2.0 * L), rtol=1e-12)
        F = rng.normal(size=(3, 3)) + 2 * np.eye(3)
        assert tensor.det3(F) == pytest.approx(np.linalg.det(F), rel=1e-12)
        assert np.allclose(tensor.inv3(F) @ F, np.eye(3), atol=1e-12)


# --------------------------------------------------------------------------- Hencky

E, NU = 50e6, 0.3  # Table 3
K, MU = E / (3 * (1 - 2 * NU)), E / (2 * (1 + NU))


def test_lame_from_young():
    k, mu = hencky.lame_from_young(E, NU)
    assert (k, mu) == pytest.approx((K, MU), rel=1e-15)


@pytest.mark.parametrize("stretch", [0.5, 0.9, 1.0, 1.3, 3.0])
def test_hencky_uniaxial_stretch_closed_form(stretch):
    F = np.diag([stretch, 1.0, 1.0])
    eps = hencky.trial_state(F, np.zeros((3, 3)))
    ln = math.log(stretch)
    assert np.allclose(eps, np.diag([ln, 0.0, 0.0]), atol=1e-15)
    tau = hencky.hencky_tau(eps, K, MU)
    expected = np.diag([(K + 4 * MU / 3) * ln, (K - 2 * MU / 3) * ln, (K - 2 * MU / 3) * ln])
    assert np.allclose(tau, expected, rtol=1e-13, atol=1e-9 * K)
    sigma = hencky.cauchy_stress(tau, F)
    assert np.allclose(sigma, tau / stretch, rtol=1e-14)


@pytest.mark.parametrize("gamma", [0.01, 0.5, 2.0])
def test_hencky_simple_shear_finite_strain(gamma):
    F = np.array([[1.0, gamma, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    eps_ref = 0.5 * logm(F @ F.T).real
    eps = hencky.trial_state(F, np.zeros((3, 3)))
    assert np.allclose(eps, eps_ref, atol=1e-13)
    tr = np.trace(eps_ref)
    tau_ref = K * tr * np.eye(3) + 2 * MU * (eps_ref - tr / 3 * np.eye(3))
    tau = hencky.hencky_tau(eps, K, MU)
    assert np.allclose(tau, tau_ref, rtol=1e-12, atol=1e-12 * MU)
    # isochoric: no pressure; the 3-direction stays unloaded in shear
    assert abs(np.trace(tau)) < 1e-9 * MU


def test_hencky_incremental_equals_total_for_elastic_path():
    rng = np.random.default_rng(RNG_SEED)
    F = np.eye(3)
    eps = np.zeros((3, 3))
    for _ in range(40):
        dF = np.eye(3) + 0.03 * rng.normal(size=(3, 3))
        F = dF @ F
        eps = hencky.trial_state(dF, eps)
    assert np.allclose(eps, 0.5 * logm(F @ F.T).real, atol=1e-12)


def test_hencky_objectivity_under_large_rigid_rotation():
    F0 = np.array([[1.2, 0.3, 0.0], [0.1, 0.9, 0.2], [0.0, -0.1, 1.1]])
    eps0 = hencky.trial_state(F0, np.zeros((3, 3)))
    tau0 = hencky.hencky_tau(eps0, K, MU)
    axis, n_steps, total = [1.0, 2.0, -0.5], 500, 3.0 * math.pi  # one and a half turns
    dR = rotation(axis, total / n_steps)
    eps, zero = eps0.copy(), np.zeros((3, 3))
    for _ in range(n_steps):
        eps = hencky.trial_state(dR, eps)
        zero = hencky.trial_state(dR, zero)
    R = rotation(axis, total)
    tau = hencky.hencky_tau(eps, K, MU)
    assert np.allclose(tau, R @ tau0 @ R.T, atol=1e-10 * np.abs(tau0).max())
    assert np.allclose(np.linalg.eigvalsh(tau), np.linalg.eigvalsh(tau0),
                       atol=1e-10 * np.abs(tau0).max())
    assert np.abs(hencky.hencky_tau(zero, K, MU)).max() < 1e-12 * MU


def test_eps_from_tau_round_trip():
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(20):
        eps = random_sym(rng, 0.1 * rng.normal(size=3))
        tau = hencky.hencky_tau(eps, K, MU)
        assert np.allclose(hencky.eps_from_tau(tau, E, NU), eps, atol=1e-15)
        assert np.allclose(hencky.eps_from_tau_kmu(tau, K, MU), eps, atol=1e-15)


def test_nominal_stress_eq27():
    rng = np.random.default_rng(RNG_SEED)
    F = np.eye(3) + 0.2 * rng.normal(size=(3, 3))
    F[2, :2] = F[:2, 2] = 0.0
    F[2, 2] = 1.0  # plane strain
    tau = hencky.hencky_tau(hencky.trial_state(F, np.zeros((3, 3))), K, MU)
    P = hencky.nominal_stress(F, tau)
    assert np.allclose(F @ P, tau, rtol=1e-12, atol=1e-12 * MU)
    assert np.allclose(P.T, tau @ np.linalg.inv(F).T, rtol=1e-12, atol=1e-12 * MU)


# --------------------------------------------------------------------------- Drucker-Prager

# Table 2 solid (residual cohesion is not in the paper: a test value)
K2, MU2 = hencky.lame_from_young(0.84e6, 0.45)
PHI2, C0_2, H2, CR2 = math.radians(19.5), 1e3, -0.1e3, 0.2e3


def test_dp_cone_matches_mohr_coulomb_in_triaxial_compression():
    c, phi = 10e3, math.radians(30.0)
    for sigma_r in (0.0, -50e3, -400e3):  # confining stress, tension positive
        # Mohr-Coulomb: sigma_1 - sigma_3 = 2 c cos(phi) - (sigma_1 + sigma_3) sin(phi)
        sigma_a = (sigma_r * (1 + math.sin(phi)) - 2 * c * math.cos(phi)) / (1 - math.sin(phi))
        tau = np.diag([sigma_a, sigma_r, sigma_r])
        assert dp.dp_yield(tau, c, phi) == pytest.approx(0.0, abs=1e-9 * abs(sigma_a))
    xi, eta, _ = dp.dp_params(phi, 0.0)
    assert xi / eta == pytest.approx(1.0 / math.tan(phi))  # apex at p = c cot(phi)
    # compression increases strength: same shear, more compression, lower Phi
    s = np.diag([-20e3, 10e3, 10e3])
    assert dp.dp_yield(s - 100e3 * np.eye(3), c, phi) < dp.dp_yield(s, c, phi)


def _random_trials(rng, n, c):
    for _ in range(n):
        s = random_sym(rng, rng.normal(size=3))
        s -= np.trace(s) / 3 * np.eye(3)
        yield c * rng.uniform(0.1, 20) * s / max(np.abs(s).max(), 1e-30) \
            + c * rng.uniform(-20, 3) * np.eye(3)


@pytest.mark.parametrize("psi_deg", [0.0, 10.0])
def test_dp_return_on_surface_and_consistent(psi_deg):
    rng = np.random.default_rng(RNG_SEED)
    psi = math.radians(psi_deg)
    n_plastic = 0
    for tau_tr in _random_trials(rng, 400, C0_2):
        eps_p0 = rng.uniform(0.0, 12.0)
        tau, eps_p, plastic = dp.dp_return(tau_tr, eps_p0, K2, MU2, C0_2, H2, CR2, PHI2, psi)
        c = dp.dp_cohesion(eps_p, C0_2, H2, CR2)
        scale = np.abs(tau_tr).max() + C0_2
        if plastic == dp.ELASTIC:
            assert np.array_equal(tau, tau_tr) and eps_p == eps_p0
            assert dp.dp_yield(tau_tr, c, PHI2) <= 1e-12 * scale
            continue
        n_plastic += 1
        assert eps_p > eps_p0 and c >= CR2
        assert abs(dp.dp_yield(tau, c, PHI2)) < 1e-8 * scale
        tau2, eps_p2, plastic2 = dp.dp_return(tau, eps_p, K2, MU2, C0_2, H2, CR2, PHI2, psi)
        assert plastic2 == dp.ELASTIC and eps_p2 == eps_p and np.array_equal(tau2, tau)
        if plastic == dp.SMOOTH_CONE:
            xi, eta, eta_bar = dp.dp_params(PHI2, psi)
            dgamma = (eps_p - eps_p0) / xi
            # non-associative flow: plastic volume change eta_bar * dgamma (none for psi=0)
            dp_mean = np.trace(tau - tau_tr) / 3
            assert dp_mean == pytest.approx(-K2 * eta_bar * dgamma, abs=1e-9 * scale)
            # deviatoric return is radial
            s_tr, q_tr = dev_q(tau_tr)
            s, q = dev_q(tau)
            assert np.allclose(s * q_tr, s_tr * q, atol=1e-9 * scale * q_tr)
    assert n_plastic > 100


@pytest.mark.parametrize("psi_deg", [0.0, 10.0])
def test_dp_apex_under_hydrostatic_tension(psi_deg):
    psi = math.radians(psi_deg)
    xi, eta, eta_bar = dp.dp_params(PHI2, psi)
    p_apex0 = xi * C0_2 / eta
    for extra_shear in (0.0, 0.05 * C0_2):
        tau_tr = 3.0 * p_apex0 * np.eye(3)
        tau_tr[0, 1] = tau_tr[1, 0] = extra_shear
        tau, eps_p, plastic = dp.dp_return(tau_tr, 0.0, K2, MU2, C0_2, 0.0, CR2, PHI2, psi)
        assert plastic == dp.APEX
        assert np.allclose(tau, p_apex0 * np.eye(3), rtol=1e-14, atol=1e-12 * C0_2)
        d_eps_v = (3.0 * p_apex0 - p_apex0) / K2
        alpha = xi / eta_bar if eta_bar > 0 else xi / eta  # Box 8.9 / tension cut-off
        assert eps_p == pytest.approx(alpha * d_eps_v, rel=1e-12)
    # with softening the apex follows the softened cohesion, never below c_r
    tau, eps_p, plastic = dp.dp_return(3.0 * p_apex0 * np.eye(3), 0.0, K2, MU2, C0_2, -5e4,
                                       CR2, PHI2, psi)
    c = dp.dp_cohesion(eps_p, C0_2, -5e4, CR2)
    assert plastic == dp.APEX and CR2 <= c < C0_2
    assert np.allclose(tau, xi * c / eta * np.eye(3), rtol=1e-12)


def test_dp_apex_when_softening_shrinks_the_cone_past_the_trial():
    H = -5e4
    xi, eta, _ = dp.dp_params(PHI2, 0.0)
    p_tr = 0.99 * xi * C0_2 / eta  # just inside the initial apex, huge shear
    tau_tr = p_tr * np.eye(3)
    tau_tr[0, 1] = tau_tr[1, 0] = 50 * C0_2
    tau, eps_p, plastic = dp.dp_return(tau_tr, 0.0, K2, MU2, C0_2, H, CR2, PHI2, 0.0)
    c = dp.dp_cohesion(eps_p, C0_2, H, CR2)
    assert plastic == dp.APEX and np.allclose(tau, xi * c / eta * np.eye(3), rtol=1e-12)
    assert eps_p >= xi * 50 * C0_2 / MU2  # at least the deviatoric plastic flow
    assert abs(dp.dp_yield(tau, c, PHI2)) < 1e-10 * C0_2


def test_dp_softening_stops_at_residual_cohesion():
    c0, H, c_r = 24.6e3, -5e3, 8e3  # Table 3, undisturbed ash (c_r: test value)
    K3, MU3 = hencky.lame_from_young(50e6, 0.3)
    phi = math.radians(35.5)
    tau = -100e3 * np.eye(3)
    eps_p, cs = 0.0, []
    d_shear = 2 * MU3 * 5e-3
    for _ in range(1000):
        tau_tr = tau.copy()
        tau_tr[0, 1] += d_shear
        tau_tr[1, 0] += d_shear
        tau, eps_new, _ = dp.dp_return(tau_tr, eps_p, K3, MU3, c0, H, c_r, phi, 0.0)
        assert eps_new >= eps_p
        eps_p = eps_new
        c = dp.dp_cohesion(eps_p, c0, H, c_r)
        cs.append(c)
        assert c >= c_r
        assert dp.dp_yield(tau, c, phi) <= 1e-8 * 100e3
    assert cs[0] < c0 and cs[-1] == c_r and eps_p > (c0 - c_r) / -H
    assert np.all(np.diff(cs) <= 0.0)
    # on the residual surface the mean stress never changed (psi = 0)
    assert np.trace(tau) / 3 == pytest.approx(-100e3, rel=1e-12)


def test_dp_elastic_state_unchanged():
    tau_tr = np.diag([-10e3, -12e3, -11e3])
    tau_tr[0, 2] = tau_tr[2, 0] = 1e3
    tau, eps_p, plastic = dp.dp_return(tau_tr, 0.3, K2, MU2, C0_2, H2, CR2, PHI2, 0.0)
    assert plastic == dp.ELASTIC and eps_p == 0.3 and np.array_equal(tau, tau_tr)
    assert tau is not tau_tr


# --------------------------------------------------------------------------- Cam-Clay

# Table 1: kappa, lambda, nu, n0 = 0.5 -> v = 1/(1 - n0) = 2, p_c = 600 kPa
KAPPA, LAM, NU1, V0, PC0 = 0.05, 0.2, 0.3, 2.0, 600e3
M1 = mcc.M_TABLE1


def test_mcc_moduli_and_m():
    Km, mum = mcc.mcc_moduli(400e3, V0, KAPPA, NU1)
    assert Km == pytest.approx(V0 * 400e3 / KAPPA)
    assert mum == pytest.approx(3 * Km * (1 - 2 * NU1) / (2 * (1 + NU1)))
    assert mcc.mcc_moduli(-5.0, V0, KAPPA, NU1)[0] == pytest.approx(V0 * mcc.P_MIN / KAPPA)
    assert mcc.m_from_phi(math.asin(3 * M1 / (6 + M1))) == pytest.approx(M1)


def test_mcc_newton_converges_in_few_iterations():
    rng = np.random.default_rng(RNG_SEED)
    iterations = []
    while len(iterations) < 300:
        p = rng.uniform(0.05, 1.0) * PC0
        q = rng.uniform(0.0, 1.0) * M1 * math.sqrt(p * (PC0 - p))
        s = random_sym(rng, rng.normal(size=3))
        s -= np.trace(s) / 3 * np.eye(3)
        tau_n = q * s / dev_q(s)[1] - p * np.eye(3)
        G = rng.normal(size=(3, 3))
        dF = np.eye(3) + 10 ** rng.uniform(-5, -2) * G / np.abs(G).max()
        tau_tr = mcc.mcc_trial(tau_n, dF, V0, KAPPA, NU1)
        if mcc.mcc_yield(tau_tr, PC0, M1) <= 0.0:
            continue
        tau, pc, de_v, dgam, it, ok = mcc.mcc_return(tau_tr, PC0, V0, KAPPA, LAM, NU1, M1)
        assert ok
        assert abs(mcc.mcc_yield(tau, pc, M1)) < 1e-8 * pc ** 2
        # flow rule (B.2) and hardening law
        p_new = -np.trace(tau) / 3
        assert de_v == pytest.approx(dgam * (2 * p_new - pc), rel=1e-8, abs=1e-12)
        assert pc == pytest.approx(PC0 * math.exp(V0 * de_v / (LAM - KAPPA)), rel=1e-12)
        iterations.append(it)
    assert max(iterations) <= 10
    assert 3 <= np.median(iterations) <= 6


def _drained_triaxial(p0, d_eps_a=-2e-3, n_steps=250):
    """Strain-driven element test at constant lateral stress -p0 (mixed control).

    Each step prescribes the axial log strain increment and finds the lateral one
    (brentq) so that the lateral stress stays -p0 to round-off.
    """
    tau, pc, v = -p0 * np.eye(3), PC0, V0
    path = []
    for _ in range(n_steps):
        def step(d_eps_r):
            dF = np.diag(np.exp([d_eps_a, d_eps_r, d_eps_r]))
            tau_tr = mcc.mcc_trial(tau, dF, v, KAPPA, NU1)
            return mcc.mcc_return(tau_tr, pc, v, KAPPA, LAM, NU1, M1)

        d_eps_r = brentq(lambda d: step(d)[0][1, 1] + p0, -abs(d_eps_a), 5 * abs(d_eps_a),
                         xtol=1e-15, rtol=1e-14)
        tau, pc, _, _, it, ok = step(d_eps_r)
        assert ok and it <= 10
        v *= math.exp(d_eps_a + 2 * d_eps_r)
        path.append((-np.trace(tau) / 3, tau[1, 1] - tau[0, 0], pc))
    return np.array(path)


def test_mcc_drained_triaxial_lightly_consolidated():
    p0 = 400e3
    path = _drained_triaxial(p0)
    p, q = path[:, 0], path[:, 1]
    assert np.abs(q - 3 * (p - p0)).max() < 1e-8 * p0  # effective stress path
    assert np.all(np.diff(q) > 0)  # hardening all the way
    assert q[-1] / (M1 * p[-1]) == pytest.approx(1.0, abs=0.01)  # on the CSL
    assert p[-1] == pytest.approx(3 * p0 / (3 - M1), rel=0.01)


def test_mcc_drained_triaxial_heavily_overconsolidated():
    p0 = 100e3
    path = _drained_triaxial(p0)
    p, q, pc = path.T
    assert np.abs(q - 3 * (p - p0)).max() < 1e-8 * p0
    k_peak = int(np.argmax(q))
    assert 0 < k_peak < len(q) // 4
    assert q[k_peak] > 1.5 * q[-1]  # peak, then softening
    assert np.all(np.diff(q[k_peak:]) < 0) and pc[-1] < PC0  # dilation softens p_c
    assert q[-1] / (M1 * p[-1]) == pytest.approx(1.0, abs=0.02)  # towards the CSL


def test_mcc_stable_as_p_goes_to_zero():
    trials = [np.zeros((3, 3)), 50e3 * np.eye(3),
              np.array([[1e5, 3e4, 0.0], [3e4, -2e4, 0.0], [0.0, 0.0, 5e3]]),
              np.array([[0.0, 2e5, 0.0], [2e5, 0.0, 0.0], [0.0, 0.0, 0.0]]),
              np.diag([-2e5 / 3, 1e5 / 3, 1e5 / 3]) - 2.0 * np.eye(3)]  # q/p' = 5e4
    for tau_tr in trials:
        for pc in (PC0, 0.0):
            tau, pc_new, de_v, dgam, it, ok = mcc.mcc_return(tau_tr, pc, V0, KAPPA, LAM, NU1, M1)
            assert ok and np.isfinite(tau).all() and np.isfinite([pc_new, de_v, dgam]).all()
            p = -np.trace(tau) / 3
            assert p > 0.0 and pc_new > 0.0
            assert mcc.mcc_yield(tau, pc_new, M1) <= 1e-8 * max(pc_new, p) ** 2
    # unloading a stress-free particle: the trial stays finite and compressive
    tau_tr = mcc.mcc_trial(np.zeros((3, 3)), 1.1 * np.eye(3), V0, KAPPA, NU1)
    assert np.isfinite(tau_tr).all() and -np.trace(tau_tr) / 3 > 0.0


def test_mcc_trial_is_objective():
    rng = np.random.default_rng(RNG_SEED)
    s = random_sym(rng, [1.0, -0.4, -0.6]) * 1e5
    tau_n = s - 300e3 * np.eye(3)
    R = rotation([0.3, -1.0, 0.2], 2.0)
    tau_tr = mcc.mcc_trial(tau_n, R, V0, KAPPA, NU1)
    assert np.allclose(tau_tr, R @ tau_n @ R.T, atol=1e-9 * 300e3)
    # pure volumetric compression follows the swelling line exactly
    J = 0.98
    tau_tr = mcc.mcc_trial(-300e3 * np.eye(3), J ** (1 / 3) * np.eye(3), V0, KAPPA, NU1)
    assert np.allclose(tau_tr, -300e3 * J ** (-V0 / KAPPA) * np.eye(3), rtol=1e-12)


def test_elastic_energy_is_the_hencky_energy_of_the_selected_non_cam_clay_rows():
    """The stored energy of stats.csv: sum V0 (mu dev e : dev e + K/2 tr(e)^2) over the
    selected rows whose model is not Cam-Clay."""
    from parsph.solid.update import C, CAM_CLAY, HENCKY, elastic_energy

    rng = np.random.default_rng(5)
    tab = np.zeros((2, len(C)))
    tab[0, C["model"]], tab[0, C["K"]], tab[0, C["mu"]] = HENCKY, 3.0e6, 1.2e6
    tab[1, C["model"]], tab[1, C["K"]], tab[1, C["mu"]] = CAM_CLAY, 9.0e9, 9.0e9
    n = 50
    e = rng.normal(scale=1e-3, size=(n, 3, 3))
    e = 0.5 * (e + e.transpose(0, 2, 1))
    material = rng.integers(0, 2, n).astype(np.int16)
    sel = rng.random(n) < 0.7
    vol = rng.random(n)
    keep = sel & (material == 0)
    tr = np.trace(e, axis1=1, axis2=2)
    dev2 = np.einsum("nij,nij->n", e, e) - tr * tr / 3.0
    expect = np.sum(vol[keep] * (1.2e6 * dev2[keep] + 0.5 * 3.0e6 * tr[keep] ** 2))
    got = elastic_energy(tab, material, sel, n, vol, e)
    assert got == pytest.approx(expect, rel=1e-12) and expect > 0
