"""The user tools: `gsp_demo`, `gsp_calibrate_client`, `gsp_plan`, `gsp_reidentify`. The nodes never import this package."""
