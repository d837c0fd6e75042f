"""A spring from the left hand to a point: the hand is pulled toward it, harder the further away.

A soft force field is no surface: it goes as the model's extra force per hand, computed every
step from the newest hand position and held by the rig until the next step (3 ms), faded like
everything else when the world stops. Keep such springs soft (tens to a few hundred N/m): stiff
things belong in proxies, which the rig renders at 1 kHz.

    python python/examples/spring.py --listen unix:/tmp/spidar-spring/world.sock
    spidar run --world unix:/tmp/spidar-spring/world.sock --script hold
"""

import spidar

LEFT = 0


class Spring(spidar.World):
    """The left hand on a 60 N/m spring to a point 5 cm in front of and 3 cm above its home."""

    name = "python spring"

    def __init__(self, k_n_per_m=60.0, d_n_s_per_m=2.0, limit_n=3.0):
        self.k_n_per_m = k_n_per_m
        self.d_n_s_per_m = d_n_s_per_m
        self.limit_n = limit_n
        self.anchor_m = None
        self.log = []  # (t_s, hand position, force sent)

    def on_connect(self, rig):
        hx, hy, hz = rig.home_m[LEFT]
        self.anchor_m = (hx, hy + 0.03, hz - 0.05)

    def step(self, t_s, samples):
        model = spidar.ContactModel()
        hand = samples[-1].hands[LEFT]
        if self.anchor_m is None or not hand.valid:
            return model
        f = [self.k_n_per_m * (a - x) - self.d_n_s_per_m * v
             for a, x, v in zip(self.anchor_m, hand.pos_m, hand.vel_m_per_s)]
        size = sum(c * c for c in f) ** 0.5
        if size > self.limit_n:
            f = [c * self.limit_n / size for c in f]
        model.extra_force_n[LEFT] = tuple(f)
        self.log.append((t_s, hand.pos_m, tuple(f)))
        return model


if __name__ == "__main__":
    spidar.main(Spring())
