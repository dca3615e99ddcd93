"""The one validation helper every parameter dataclass uses: the message names the class,
the field, its valid range and the value; NaN fails every range."""

import dataclasses
import math

import pytest

from jaxloco import validation as v


@dataclasses.dataclass(frozen=True)
class Demo:
    rate: float = 1.0
    share: float = 0.5
    count: float = 3
    kind: str = "a"

    def __post_init__(self):
        v.check_fields(
            self,
            [
                *v.positive(self, "rate"),
                *v.unit_interval(self, "share"),
                v.integer(self, "count", 1),
                v.one_of(self, "kind", ("a", "b")),
            ],
        )


def test_messages_name_the_class_field_range_and_value():
    Demo()
    with pytest.raises(ValueError, match=r"^Demo\.rate must be > 0; got -1\.0$"):
        Demo(rate=-1.0)
    with pytest.raises(ValueError, match=r"Demo\.share must be in \[0, 1\]; got nan"):
        Demo(share=math.nan)
    with pytest.raises(ValueError, match=r"Demo\.count must be an int >= 1; got 2\.5"):
        Demo(count=2.5)
    with pytest.raises(ValueError, match=r"Demo\.kind must be one of \['a', 'b'\]; got 'c'"):
        Demo(kind="c")
    with pytest.raises(ValueError, match="Demo.rate"):
        Demo(rate=math.nan)
