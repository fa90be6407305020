"""Geodesics on the depth surface: the grid mesh, the straightest-geodesic walk, heat-method
distances, and the polar patches built from them."""
