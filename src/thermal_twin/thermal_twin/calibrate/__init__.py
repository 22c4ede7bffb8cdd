"""Fitting a twin's existing parameters to a recording (``thermal-comp calibrate``), estimating
inputs the recording lacks, and the calibration report."""
