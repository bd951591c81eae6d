"""Everyday English words the recognizer may hear instead of a command: its garbage model.

Chat has to decode as *something*; without these words the decoder can only pick the nearest
command ("I forgot my umbrella" came out as "what time is it"). A general list, not tuned on the
chat lines the benchmark measures with. Command words are in the model anyway.
"""

from __future__ import annotations

FILLER_WORDS: tuple[str, ...] = tuple(
    """
    a about after again all also am an and any are as at away be because been before being but by
    can could day did do does doing done down each even every few find first for from get give go
    going good got had has have he her here him his how i if in into is it its just know let like
    little long make man many may me more most much must my never new no not now of off okay old on
    one only or other our out over people please put really right said same say see she should so
    some still such take tell than thank that the their them then there these they thing think this
    those through time to today too two up us very want was way we well went were what when where
    which while who why will with work would yeah year yes yet you your
    """.split()
)
