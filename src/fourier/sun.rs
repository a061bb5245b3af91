//! Sun visibility from a horizon: the lit fraction of the sun's disc (placeholder).
