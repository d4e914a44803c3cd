"""KUKA KR C2: EKI (Ethernet KRL XML) and RSI codecs (pure), one link per channel, and the client (interfaces.Robot)."""
