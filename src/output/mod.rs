//! What the tracker shows a person: frames with the ellipse, pan and tilt bars, the angles.
