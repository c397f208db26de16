"""Per-anchor bias states: the firmware's decoupled scalar filters against a full joint EKF.

    python scripts/joint_states_probe.py RECORDING... --anchors ANCHORS.csv --model util_tdoa_pos.npz
        [--tau 0.3] [--std 0.12]

One numpy filter (float64, UWB-only TDoA): constant velocity (proc_cv_acc 2), 16 anchor biases as
first-order Gauss-Markov states, the network's correction at the estimate above 0.5 m, std_tdoa 0.15,
chi-square gate 3.841 (no kinematic gate). Run twice per recording: "joint" keeps every covariance
(position, velocity, biases: 22 x 22), "decoupled" zeroes the cross-covariances before each update,
which is what core/bias_states.c does with its scalar states. Prints both position RMSEs.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from harness.biasnet.network import BiasModel
from harness.config import EstimatorConfig
from harness.biasnet.recipes import load_recordings
from harness.flight.data import Flight
from harness.twin.features import features
from protocol.messages import MAX_ANCHORS

N_ANCHORS = MAX_ANCHORS
# the firmware's power-up configuration (protocol/messages.toml), not a copy of its numbers
_FW = EstimatorConfig()
STD_TDOA, PROC_CV_ACC, CHI2, NN_MIN_Z = _FW.std_tdoa, _FW.proc_cv_acc, _FW.chi2_tdoa, _FW.nn_min_z


def predict(x: np.ndarray, P: np.ndarray, dt: float, tau: float, std: float) -> tuple[np.ndarray, np.ndarray]:
    n = len(x)
    F = np.eye(n)
    F[:3, 3:6] = np.eye(3) * dt
    a = math.exp(-dt / tau)
    F[6:, 6:] *= a
    Q = np.zeros((n, n))
    q2 = PROC_CV_ACC ** 2
    for j in range(3):
        Q[j, j], Q[3 + j, 3 + j] = q2 * dt ** 3 / 3, q2 * dt
        Q[j, 3 + j] = Q[3 + j, j] = q2 * dt ** 2 / 2
    Q[6:, 6:] = np.eye(N_ANCHORS) * std ** 2 * (1 - a * a)
    return F @ x, F @ P @ F.T + Q


def run(flight: Flight, net: object, tau: float, std: float, decoupled: bool) -> float:
    anchors, u = flight.anchors.as_dict(), flight.uwb
    n = 6 + N_ANCHORS
    x = np.zeros(n)
    x[:3] = flight.truth.position_at(u.t_us[:1])[0]
    P = np.diag([1.0] * 3 + [0.25] * 3 + [std ** 2] * N_ANCHORS)
    est = np.empty((len(u), 3))
    for k in range(len(u)):
        if k and u.t_us[k] > u.t_us[k - 1]:
            x, P = predict(x, P, (u.t_us[k] - u.t_us[k - 1]) * 1e-6, tau, std)
        a, b = int(u.anchor_a[k]), int(u.anchor_b[k])
        pa, pb, p = anchors[a], anchors[b], x[:3]
        H = np.zeros(n)
        H[:3] = (p - pb) / np.linalg.norm(p - pb) - (p - pa) / np.linalg.norm(p - pa)
        H[6 + a], H[6 + b] = -1.0, 1.0
        bias = float(net.predict(features(int(net.layout), p, np.zeros(3), pa, pb))) if p[2] > NN_MIN_Z else 0.0
        y = u.value[k] - bias - (np.linalg.norm(p - pb) - np.linalg.norm(p - pa)) - (x[6 + b] - x[6 + a])
        if decoupled:
            P = np.block([[P[:6, :6], np.zeros((6, N_ANCHORS))],
                          [np.zeros((N_ANCHORS, 6)), np.diag(np.diag(P[6:, 6:]))]])
        PH = P @ H
        S = float(H @ PH) + STD_TDOA ** 2
        if y * y / S <= CHI2:
            K = PH / S
            x = x + K * y
            IKH = np.eye(n) - np.outer(K, H)
            P = IKH @ P @ IKH.T + np.outer(K, K) * STD_TDOA ** 2
        est[k] = x[:3]
    ok = (u.t_us >= flight.truth.t_us[0]) & (u.t_us <= flight.truth.t_us[-1])
    err = est[ok] - flight.truth.position_at(u.t_us[ok])
    return float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recordings", type=Path, nargs="+")
    ap.add_argument("--anchors", type=Path, default=None)
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--tau", type=float, default=0.3)
    ap.add_argument("--std", type=float, default=0.12)
    args = ap.parse_args()
    net = BiasModel.load(args.model).tdoa
    for path, flight in zip(args.recordings, load_recordings(args.recordings, args.anchors)):
        joint, dec = (run(flight, net, args.tau, args.std, d) for d in (False, True))
        print(f"{path.name}: joint {joint:.4f} m, decoupled {dec:.4f} m", flush=True)


if __name__ == "__main__":
    main()
