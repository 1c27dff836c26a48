"""kincal in Python (docs/tutorials/python.md): the README's example, the files the
command line writes read back, and what a notebook displays."""

import subprocess  # the files step runs the command line

# --8<-- [start:example]
import numpy as np

import kincal

rng = np.random.default_rng(0)
nominal = kincal.load_robot("puma560")
truth = kincal.perturb_robot(nominal, rng)                 # 1 mm / 0.05° / 0.1° errors
q = kincal.random_configurations(nominal, 60, rng)
data = kincal.simulate_positions(truth, q, rng, noise_std=1e-5)  # a laser tracker, 0.01 mm
result = kincal.calibrate(nominal, [data], prior="tolerances")   # as `kincal calibrate` does
print(result.summary())                # estimates, standard errors, what is not identifiable
print(result.identifiability.describe()[8])  # "d[3] cannot be told apart from d[2]: ..."

q_new = kincal.random_configurations(nominal, 20, rng)       # poses the fit never saw
held_out = kincal.simulate_positions(truth, q_new, rng, noise_std=1e-5)
print(kincal.validate(result.robot, [held_out], result))    # held-out errors (mm; SI inside)
accuracy = kincal.accuracy_model(result)
print(kincal.predict_accuracy(accuracy, result.robot, q_new).summary())  # predicted there

targets = truth.fk(q_new[:5])                               # where the tool must go
commands = kincal.compensate(result.robot, targets, nominal=nominal)
print(commands)                        # joint commands, and targets for a nominal controller
# --8<-- [end:example]

# --8<-- [start:files]
subprocess.run(["kincal", "simulate", "puma560", "-o", "train.csv", "-n", "40", "--noise",
                "0.01mm", "--seed", "3", "--holdout", "holdout.csv", "--holdout-poses", "20"],
               check=True, capture_output=True)
robot = kincal.load_robot("puma560")
blocks = kincal.read_measurements("train.csv", robot)     # units from the column headers
print([f"{type(b).__name__} '{b.name}', {len(b.q)} poses" for b in blocks])
estimator = kincal.Calibration(robot, stages=["offsets", "all"], prior="tolerances")
result = estimator.fit(blocks).result_
print(repr(result))
held = kincal.read_measurements("holdout.csv", robot)
print({k: f"{v * 1e3:.4f} mm" if k.endswith("_m") else v
       for k, v in kincal.validate(result.robot, held, result)["overall"].items()})
kincal.write_robot(result.robot, "calibrated.yaml")       # what `kincal calibrate -o` writes
print(open("calibrated.yaml").read().splitlines()[0])
# --8<-- [end:files]

# --8<-- [start:notebook]
with open("calibration.html", "w", encoding="utf-8") as f:   # what Jupyter displays
    f.write("<!doctype html><meta charset=utf-8><title>CalibrationResult</title>"
            + result._repr_html_())
print(f"{len(result._repr_html_())} characters of HTML -> calibration.html")
# --8<-- [end:notebook]
