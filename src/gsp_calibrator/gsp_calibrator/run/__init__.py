"""One calibration run: its course (the coroutine the node awaits), what it needs from the node, its files and state, the posture selection and the identification of its rows."""
