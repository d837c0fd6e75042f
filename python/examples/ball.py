"""A ball on a table that you push, and that rolls away.

The ball is a sphere proxy; every step the world adds the impulses the rig reports for it (what
the user's hand really gave it, after the rig's clamps) to its momentum, lets it roll with a
little rolling resistance, bounces it off the table's edges, and sends it where it is now with
its velocity (the rig moves it along between two steps). The table is a plane proxy.

    python python/examples/ball.py --listen unix:/tmp/spidar-ball/world.sock
    spidar run --world unix:/tmp/spidar-ball/world.sock --script FILE.ron
"""

import math

import spidar

TABLE_Y_M = 0.90  # world frame: 20 cm below the rig's origin
BALL = 0  # proxy index of the ball (the table is 1)


class Ball(spidar.World):
    """A 0.3 kg ball of radius 6 cm rolling on a table top."""

    name = "python ball"

    def __init__(self, start_m=(0.15, TABLE_Y_M + 0.06, -0.20), mass_kg=0.3, radius_m=0.06, roll_tau_s=1.5):
        self.pos_m = list(start_m)
        self.vel_m_per_s = [0.0, 0.0, 0.0]
        self.mass_kg = mass_kg
        self.radius_m = radius_m
        self.roll_tau_s = roll_tau_s
        # The table's edges (world x and z), where the ball bounces.
        self.x_range_m = (-0.40, 0.40)
        self.z_range_m = (-0.60, 0.05)
        self.last_t_s = None
        self.pushed_n_s = 0.0  # horizontal impulse taken in all

    def step(self, t_s, samples):
        dt = 0.0 if self.last_t_s is None else t_s - self.last_t_s
        self.last_t_s = t_s
        jx, _, jz = spidar.impulse_on(samples, BALL)
        self.pushed_n_s += math.hypot(jx, jz)
        # The table carries the ball's weight: only the horizontal push moves it.
        self.vel_m_per_s[0] += jx / self.mass_kg
        self.vel_m_per_s[2] += jz / self.mass_kg
        decay = math.exp(-dt / self.roll_tau_s)
        for i, (lo, hi) in ((0, self.x_range_m), (2, self.z_range_m)):
            self.vel_m_per_s[i] *= decay
            self.pos_m[i] += self.vel_m_per_s[i] * dt
            if not lo + self.radius_m <= self.pos_m[i] <= hi - self.radius_m:
                self.pos_m[i] = min(max(self.pos_m[i], lo + self.radius_m), hi - self.radius_m)
                self.vel_m_per_s[i] *= -0.5
        ball = spidar.Proxy(
            spidar.Sphere(centre_m=tuple(self.pos_m), radius_m=self.radius_m),
            k_n_per_m=1000.0,
            d_n_s_per_m=5.0,
            vel_m_per_s=tuple(self.vel_m_per_s),
        )
        table = spidar.Proxy(spidar.Plane(point_m=(0.0, TABLE_Y_M, 0.0), normal=(0.0, 1.0, 0.0)), k_n_per_m=2000.0,
                             d_n_s_per_m=5.0)
        return [ball, table]


if __name__ == "__main__":
    spidar.main(Ball())
