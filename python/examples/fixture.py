"""A virtual fixture: a guide that keeps the right hand on a straight line and lets it slide
freely along it (the kind used to guide a motion to be learned or a tool along a path).

The force pulls the hand back toward the nearest point of the line, across the line only (a
spring and a damper on the hand's offset from it), as the model's extra force for the right
hand; nothing resists motion along the line.

    python python/examples/fixture.py --listen unix:/tmp/spidar-fixture/world.sock
    spidar run --world unix:/tmp/spidar-fixture/world.sock --script circle
"""

import spidar

RIGHT = 1


def _sub(a, b):
    return [x - y for x, y in zip(a, b)]


def _dot(a, b):
    return sum(x * y for x, y in zip(a, b))


class Fixture(spidar.World):
    """The right hand guided along a line through its home point, pointing forward and down."""

    name = "python fixture"

    def __init__(self, k_n_per_m=300.0, d_n_s_per_m=3.0, limit_n=4.0, direction=(0.0, -0.6, -0.8)):
        self.k_n_per_m = k_n_per_m
        self.d_n_s_per_m = d_n_s_per_m
        self.limit_n = limit_n
        n = _dot(direction, direction) ** 0.5
        self.direction = [c / n for c in direction]
        self.origin_m = None
        self.log = []  # (t_s, hand position, force sent)

    def on_connect(self, rig):
        self.origin_m = list(rig.home_m[RIGHT])

    def across(self, v):
        """The part of ``v`` across the line."""
        along = _dot(v, self.direction)
        return [c - along * u for c, u in zip(v, self.direction)]

    def step(self, t_s, samples):
        model = spidar.ContactModel()
        hand = samples[-1].hands[RIGHT]
        if self.origin_m is None or not hand.valid:
            return model
        off = self.across(_sub(hand.pos_m, self.origin_m))
        vel = self.across(hand.vel_m_per_s)
        f = [-self.k_n_per_m * o - self.d_n_s_per_m * v for o, v in zip(off, vel)]
        size = _dot(f, f) ** 0.5
        if size > self.limit_n:
            f = [c * self.limit_n / size for c in f]
        model.extra_force_n[RIGHT] = tuple(f)
        self.log.append((t_s, hand.pos_m, tuple(f)))
        return model


if __name__ == "__main__":
    spidar.main(Fixture())
