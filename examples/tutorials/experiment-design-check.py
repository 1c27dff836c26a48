"""Experiment design, checked (docs/tutorials/experiment-design.md): do planned poses beat
random ones on poses the fit never saw?  Twenty simulated PUMA 560s, each calibrated once
from the 15 planned poses, once from 15 random poses and once from 30 random poses, all
measured by a simulated laser tracker (0.01 mm per coordinate); each calibrated model is
compared with its true robot at 200 random poses the fit never saw."""

# --8<-- [start:check]
import numpy as np

import kincal

nominal = kincal.load_robot("puma560")
plan = kincal.plan_poses(nominal, poses=15, criterion="O1", seed=0)   # as `kincal plan`
print(plan)


def held_out_rms_mm(q, truth, rng) -> float:
    """Calibrate from poses q; the model's RMS position error at 200 new poses [mm]."""
    data = kincal.simulate_positions(truth, q, rng, noise_std=1e-5)    # 0.01 mm tracker
    result = kincal.calibrate(nominal, [data], prior="tolerances")     # the CLI default
    q_new = kincal.random_configurations(nominal, 200, rng)
    exact = kincal.simulate_positions(truth, q_new, rng, noise_std=0.0)  # the true robot
    # result as extras: the tracker frame and marker as calibrated (same session)
    return kincal.validate(result.robot, [exact], result)["overall"]["rms_position_m"] * 1e3


designs = {"15 planned (O1)": [], "15 random": [], "30 random": []}
for k in range(20):
    rng = np.random.default_rng(100 + k)
    truth = kincal.perturb_robot(nominal, rng)           # a robot with its own errors
    designs["15 planned (O1)"].append(held_out_rms_mm(plan.q, truth, rng))
    designs["15 random"].append(
        held_out_rms_mm(kincal.random_configurations(nominal, 15, rng), truth, rng))
    designs["30 random"].append(
        held_out_rms_mm(kincal.random_configurations(nominal, 30, rng), truth, rng))

print("\nRMS position error at 200 held-out poses, 20 simulated robots [mm]")
print(f"{'poses':<16} {'median':>8} {'90 %':>8} {'max':>8}")
for name, rms in designs.items():
    rms = np.array(rms)
    print(f"{name:<16} {np.median(rms):8.4f} {np.percentile(rms, 90):8.4f} {rms.max():8.4f}")
wins = sum(p < r for p, r in zip(designs["15 planned (O1)"], designs["15 random"], strict=True))
print(f"15 planned poses beat 15 random ones on {wins} of 20 robots")
# --8<-- [end:check]
