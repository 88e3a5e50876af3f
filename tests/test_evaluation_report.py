"""The report puts this run's improvement factors beside the paper's and lists the figures."""

from hybridfmu.evaluation.metrics import improvement_factors
from hybridfmu.evaluation.report import ReportFigure, render_report


def _metrics(role, fmu, neural):
    zoom = {"maneuver": role, "quantity": "angle", "source": "auto", "t_start_s": 1.0, "t_end_s": 3.0,
            "fmu": fmu, "neural_fmu": neural, "improvement": improvement_factors(fmu, neural)}
    return {"fmu": fmu, "neural_fmu": neural, "improvement": improvement_factors(fmu, neural), "zooms": [zoom]}


def test_report_tables_and_verdicts():
    fmu = {"angle_mae": 10.0, "angle_mse": 200.0, "speed_mae": 6.0, "speed_mse": 90.0}
    good = {"angle_mae": 1.0, "angle_mse": 2.0, "speed_mae": 2.0, "speed_mse": 10.0}    # x10, x100, x3, x9
    weak = {"angle_mae": 5.0, "angle_mse": 100.0, "speed_mae": 6.0, "speed_mse": 90.0}  # x2, x2, x1, x1
    text = render_report(
        "tiny", {"validation": _metrics("validation", fmu, good), "test": _metrics("test", fmu, weak)},
        {"lr": 3e-6, "width": 8}, {"trial": "t007"}, dt_s=-2.0e-5, gates=[0.9, 0.3], true_dt_s=-5.0e-5,
        truth_source="raw/test.truth.json", figures=[ReportFigure("figures/test_angle.png", "Test angle")],
        mlflow_run={"run_id": "abc", "experiment": "tiny", "tracking_uri": "sqlite:///x.db"})
    assert "| validation | angle | MAE | 10 rad | 1 rad | ×10 | ×4.6 (Figs. 9-10) |" in text
    assert "| test | angle | MSE | 200 rad² | 100 rad² | ×2 | ×74 (Fig. 13) |" in text
    assert "validation angle MSE: ×100 against the paper's ×61 (Figs. 9-10) — reached." in text
    assert "test angle MAE: ×2 against the paper's ×5.4 (Fig. 13) — not reached." in text
    assert "learned minus true: 30.00 µs" in text
    assert "![Test angle](figures/test_angle.png)" in text
    assert "| lr | 3e-06 |" in text and "Evaluation run `abc`" in text


def test_report_without_truth():
    fmu = {"angle_mae": 1.0, "angle_mse": 1.0, "speed_mae": 1.0, "speed_mse": 1.0}
    text = render_report("user", {"test": _metrics("test", fmu, fmu)}, {}, {}, dt_s=1e-6, gates=None,
                         true_dt_s=None, truth_source=None, figures=[], mlflow_run=None)
    assert "no ground truth" in text and "| validation |" not in text
