"""The mock KUKA KR C4 / KR C5 (KSS 8): EKI server, RSI 4.x/5.x UDP stream with axis corrections."""
