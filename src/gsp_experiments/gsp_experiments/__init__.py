"""Experiments on the gsp_kinematics core: the paper's reproduction, nominal sets and benchmark.

Pure numpy/scipy/matplotlib (never imports rclpy). Modules: :mod:`~gsp_experiments.tables` (the
paper's tables, shipped as package data), :mod:`~gsp_experiments.nominal_sets`,
:mod:`~gsp_experiments.paper` (``gsp_paper``) and :mod:`~gsp_experiments.bench` (the core's
sections of ``gsp_bench``).
"""
