"""Serial meteo sensor: line codec (pure) and client (interfaces.Meteo)."""
