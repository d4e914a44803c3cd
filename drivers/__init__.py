"""Device drivers: one interface per device kind and the real clients behind them.

`drivers` imports nothing of trackcal's other packages (see DESIGN.md).
"""
