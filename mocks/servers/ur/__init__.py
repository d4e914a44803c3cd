"""Mock Universal Robots e-Series controller (RTDE, dashboard, script ports, primary interface) in its own process."""
