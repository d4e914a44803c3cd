"""Cell PLC over Modbus TCP: register map codec (pure) and client (interfaces.CellIO)."""
