"""The typed fields of ``settings.CalibratorSettings``, one per parameter of the table, for a type
checker and an editor (``test_settings.py`` fails, printing the text, when they differ)."""

import dataclasses

from gsp_kinematics.model.geometry import Geometry


@dataclasses.dataclass(frozen=True)
class ParameterFields:
    """One typed field per calibrator parameter, and the loaded nominal geometry."""

    nominal: Geometry
    nominal_geometry_file: str
    posture_count: int
    pool_size: int
    workspace_postures: int
    pairs_per_posture: int
    sync_tolerance: float
    settle_timeout: float
    max_posture_error: float
    rest_lookback: float
    rest_sigmas: float
    topic_timeout: float
    startup_timeout: float
    seed: int
    free_parameters: tuple[str, ...]
    payload_mass: float
    payload_centre_of_mass: tuple[float, ...]
    leg_mass: tuple[float, ...]
    loss: str
    loss_scale: float
    outlier_threshold: float
    noise_source: str
    required_position_accuracy_mm: float
    required_orientation_accuracy_deg: float
    required_improvement_over_nominal: float
    cross_validation_folds: int
    formulation: str
    sigma_leg_lengths: float
    sigma_inclinometer: float
    sigma_encoder: float
    sigma_lvdt: float
    posture_order: str
    max_leg_speed: float
    max_leg_acceleration: float
    output_root: str
    write_report_plots: bool
    resume_run_directory: str
    apply_result: bool
    platform_node_name: str
    controller_effects: str
    platform_id: str
    check_geometry_file: str
    stop_when_accurate: bool
    stop_confidence: float
    stop_minimum_postures: int
    stop_every: int
    stop_max_added: int
    reuse_rows_from: str
    diagnostics_period: float
