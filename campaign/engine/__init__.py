"""The campaign engine: steps, the engine that executes them, recording and playback, wiring, the operator."""
