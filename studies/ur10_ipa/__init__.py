"""The IPA UR10 real-data study: calibrate on Series B, validate on Series D."""
