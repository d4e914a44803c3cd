"""Universal Robots arms (CB3, e-Series) through ur_rtde: the client (client.py) and its hardware-file family
(family.py)."""
