"""The mock ABB controller (RobotWare): Robot Web Services over HTTP and EGM over UDP, driven by the twin."""
