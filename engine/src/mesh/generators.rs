//! Mesh generators for the test geometries (plane, open box, cylinder, funnel, auger).
