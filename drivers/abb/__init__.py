"""ABB robot controllers (RobotWare): Robot Web Services, EGM and RAPID programs."""
