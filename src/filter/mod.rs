//! The particle filter over `(cx, cy, a, b, rx, ry, rz)`.
