"""KUKA KR C4 / KR C5 (KSS 8): EthernetKRL 3.x and RSI 4.x/5.x, sharing the KR C2 codecs (drivers/kuka)."""
