"""The paper reproduction and the benchmark: their building blocks and output contracts (small runs)."""

import json
import math
import sys
import types

import numpy as np
import pytest

from gsp_kinematics import bench, paper
from gsp_kinematics.device import device_readings
from gsp_kinematics.identification import Sigmas
from gsp_kinematics.kinematics import inverse_kinematics


def test_tables_come_from_the_shared_file_or_the_embedded_copy(tmp_path, monkeypatch):
    tables, source = paper.load_tables()
    initial, levels = paper.table3(tables)
    assert initial == {"position_mm": 1.344, "orientation_deg": 0.345}
    assert [(level["angle_noise_deg"], level["length_noise_mm"]) for level in levels] == [
        (0.001, 0.001),
        (0.001, 0.005),
        (0.005, 0.001),
        (0.005, 0.005),
    ]
    assert paper.table3(paper.EMBEDDED_TABLES) == (initial, levels)  # the fallback copy agrees
    monkeypatch.setattr(paper, "_table_candidates", lambda: [tmp_path / "absent.yaml"])
    assert paper.load_tables() == (paper.EMBEDDED_TABLES, "embedded")
    with pytest.raises(FileNotFoundError):
        paper.load_tables(tmp_path / "absent.yaml")


def test_noise_model_hits_the_right_sensors(rng):
    legs, readings = np.zeros((20000, 6)), np.zeros((20000, 4))
    noisy_legs, noisy_readings = paper.add_noise(legs, readings, 0.005, 0.001, rng)
    assert np.std(noisy_legs) == pytest.approx(1e-6, rel=0.02)
    np.testing.assert_allclose(
        np.std(noisy_readings, axis=0), [math.radians(0.005)] * 3 + [1e-6], rtol=0.03
    )


def test_json_is_strict(tmp_path):
    path = tmp_path / "out" / "doc.json"
    paper.write_json(
        {"a": np.float64(1.5), "b": [np.nan, np.inf], "c": np.int64(3), "d": np.bool_(True)}, path
    )
    assert json.loads(path.read_text()) == {"a": 1.5, "b": [None, None], "c": 3, "d": True}


def test_paper_main_writes_the_contract(tmp_path, capsys):
    output = tmp_path / "paper.json"
    code = paper.main(
        [
            "--seeds",
            "1",
            "--pool",
            "80",
            "--sets",
            "1",
            "--formulations",
            "paper,implicit",
            "--jobs",
            "1",
            "--output",
            str(output),
            "--plot-dir",
            str(tmp_path),
        ]
    )
    assert code == 0
    document = json.loads(output.read_text())
    assert {"position_mm", "orientation_deg"} <= set(document["initial"])
    assert document["initial"]["position_mm"] > 0.1
    (row,) = document["noise_free"]
    assert row["set"] == 1 and row["converged"] is True
    assert row["max_param_error_mm"] < 1e-6 and row["max_param_error_deg"] < 1e-6
    assert len(row["parameters"]) == 44
    assert len(document["noise"]) == 8
    for entry in document["noise"]:
        assert {
            "angle_noise_deg",
            "length_noise_mm",
            "formulation",
            "seeds",
            "position_mm",
            "orientation_deg",
            "paper_position_mm",
            "paper_orientation_deg",
        } <= set(entry)
        assert entry["formulation"] in ("paper", "implicit") and entry["seeds"] == 1
        assert 0.0 < entry["position_mm"] < document["initial"]["position_mm"]
    assert (tmp_path / "paper_fig6_set1_parameter_errors.png").stat().st_size > 10000
    assert "Table 3" in capsys.readouterr().out


def test_scipy_baseline_residuals_vanish_at_the_exact_geometry(
    exact, nominal_sets, moderate_postures
):
    poses = moderate_postures[:20]
    legs, readings = inverse_kinematics(exact, poses), device_readings(exact, poses)
    residuals = bench.fk_residual_function(nominal_sets[2], legs, readings, Sigmas(), poses)
    assert residuals(exact.to_vector()).shape == (80,)
    assert np.max(np.abs(residuals(exact.to_vector()))) < 1e-6
    assert np.max(np.abs(residuals(nominal_sets[2].to_vector()))) > 10.0


def test_fk_throughput_section():
    section = bench.bench_fk(count=300, repeats=1)
    assert section["postures_per_s"] > 0 and section["converged_fraction"] == 1.0
    assert section["max_position_error_m"] < 1e-9


def test_bench_json_merges_and_extra_sections_register(tmp_path, monkeypatch):
    path = tmp_path / "bench.json"
    path.write_text(json.dumps({"end_to_end": {"seconds": 12.0}, "fk": {"postures_per_s": 1.0}}))
    document = bench.merge_sections(path, {"fk": {"postures_per_s": 2.0}})
    assert document == {"end_to_end": {"seconds": 12.0}, "fk": {"postures_per_s": 2.0}}
    assert json.loads(path.read_text()) == document
    assert bench.merge_sections(path, {"fk": {}}, merge=False) == {"fk": {}}

    module = types.ModuleType("fake_bench_section")
    module.run = lambda quick=False: {"quick": quick, "value": 1.0}
    monkeypatch.setitem(sys.modules, "fake_bench_section", module)
    monkeypatch.setattr(
        bench, "EXTRA_SECTIONS", {"fake": "fake_bench_section", "absent": "no_such_module_xyz"}
    )
    logged = []
    assert bench.extra_sections(quick=True, log=logged.append) == {
        "fake": {"quick": True, "value": 1.0}
    }
    assert any("absent" in line for line in logged)
    assert bench.extra_sections(skip={"fake"}, log=logged.append) == {}
