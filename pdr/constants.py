"""Physical constants used across firetrack (SI units)."""

GRAVITY = 9.80665  # m/s², standard gravity (ISO 80000-3); also the size of one "g"
