"""The mock KUKA KR C2 (MockKrc2 in controller.py): its motion model, its EKI and RSI socket ends."""
