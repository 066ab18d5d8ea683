"""The verdict on a calibration: its accuracy measured by the device on postures the fit did
not use (cross_validation), the acceptance against what the user needs (acceptance), and the
model chosen from the data (model_choice)."""
