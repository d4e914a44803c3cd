"""KUKA KR C2: EKI (Ethernet KRL XML) and RSI codecs (pure) and the client (interfaces.Robot)."""
