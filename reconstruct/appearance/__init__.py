"""Appearance carried from the seen to the unseen side of an avatar, without learned weights:
the wrap-around fill (``wrap_fill``) and the earlier screened-harmonic fill with mirrored colours
(``propagation``). Stage I's unseen fill and Stage II's built-in prior both use them."""
