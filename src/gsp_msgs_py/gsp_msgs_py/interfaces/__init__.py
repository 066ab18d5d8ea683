"""The suite's interface contract for drivers: its conformance rules (``rules``, pure) and the
``gsp_check_interfaces`` tool that applies them to a running graph (``check_tool``; docs/hardware.md)."""
