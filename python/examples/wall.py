"""A wall in front of the user: the front wall of the rig-check scene (configs/scene-walls.ron),
as a Python world. Press into it and feel k x depth.

Run it, then connect a rig to the address it prints:
    python python/examples/wall.py --listen unix:/tmp/spidar-wall/world.sock
    spidar run --world unix:/tmp/spidar-wall/world.sock --script tour
"""

import spidar


class Wall(spidar.World):
    """A stiff wall 30 cm in front of the rig's origin (world z = -0.30 m)."""

    name = "python wall"

    def step(self, t_s, samples):
        wall = spidar.Plane(point_m=(0.0, 1.10, -0.30), normal=(0.0, 0.0, 1.0))
        return [spidar.Proxy(wall, k_n_per_m=2000.0, d_n_s_per_m=5.0)]


if __name__ == "__main__":
    spidar.main(Wall())
