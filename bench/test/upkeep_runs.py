"""Run directories of simulated calibrations of one platform (the benches' pure path), as the
calibrator writes them (``result.json``), for the upkeep tests."""

from gsp_bench.upkeep import UpkeepDesign, changed_truth
from gsp_calibrator.report.write import ReportInputs, write_result_json
from gsp_kinematics.model.geometry import save_geometry

#: (directory name, truth changed?, noise seed): two calibrations of the unchanged platform,
#: then one after Loff3 moved by 20 um.
RUNS = (
    ('20261101T080000Z', False, 21),
    ('20261108T080000Z', False, 22),
    ('20261115T080000Z', True, 22),
)


def write_runs(root, platform='hexapod-7'):
    """The three run directories under ``root``: ``{name: (path, IdentificationResult)}``."""
    design = UpkeepDesign.default()
    changed = changed_truth(design.true, 'Loff3', 20e-6)
    written = {}
    for name, is_changed, seed in RUNS:
        path = root / name
        path.mkdir(parents=True)
        result = design.identify(changed if is_changed else design.true, seed)
        inputs = ReportInputs(
            nominal=design.nominal,
            extra={'success': True, 'options': {'platform_id': platform}},
        )
        write_result_json(path, result, inputs)
        save_geometry(result.geometry, path / 'result.yaml')
        written[name] = (path, result)
    return written
