"""trackcal: industrial robot calibration with a laser tracker. Installed, this is the one import package; its
sub-packages are the repository's rooms (calib, drivers, mocks, campaign, configs: see the README's Layout)."""
