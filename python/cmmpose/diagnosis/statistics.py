"""The diagnosis's statistical constants and the chi-square tail they use,
shared by the selection (:mod:`.identify`), its cross-validation (:mod:`.cv`)
and the noise floor (:mod:`.floor`)."""

from __future__ import annotations

from scipy.special import chdtrc

__all__ = ["ALPHA", "CLAIM_FAMILIES", "INDISTINGUISHABLE", "INDISTINGUISHABLE_LR", "NOT_OBSERVABLE_BELOW",
           "OBSERVABLE_AT", "PRIOR_WEIGHT", "RSS_FLOOR", "SIGMA_FLOOR", "chi2_sf"]

#: Family-wise false-alarm rate of a proposal, and of every other family of tests whose rejection is a claim about
#: the machine (see CLAIM_FAMILIES).
ALPHA = 1e-3
#: The families of tests a diagnosis makes on a run, each rejection a claim about the machine
#: (:attr:`cmmpose.diagnosis.result.Diagnosis.claims`), each at ALPHA family-wise (Bonferroni over its own
#: members): the library's named effects, the map corrections and the cross-axis corrections (:mod:`.identify`;
#: an ambiguity set needs a significant leader among them), the two-axis errors and the noise floor
#: (:mod:`.floor`), the periodic errors along an axis (:mod:`.unexplained`) and the residual patterns
#: (:mod:`.patterns`). On a machine with no error beyond its maps the chance that a run carries any claim is at
#: most CLAIM_FAMILIES * ALPHA (the union bound), 0.7 %: within issue 33's promise of 1 %.
CLAIM_FAMILIES = 7
#: Squared signal-to-noise, at the prior magnitude, below which an effect
#: counts as unobservable in the run (5 sigma).
OBSERVABLE_AT = 25.0
#: Squared signal-to-noise at the prior magnitude below which the run cannot
#: determine an effect at a typical size (2 sigma): "not observable". Between
#: this and OBSERVABLE_AT an effect is determined, if weakly: "not significant".
NOT_OBSERVABLE_BELOW = 4.0
#: Two candidates whose fitted contributions correlate above this cannot be
#: told apart.
INDISTINGUISHABLE = 0.95
#: ... and whose likelihood-ratio gains differ by less than this (a
#: likelihood ratio under e^5, about 150:1, between them).
INDISTINGUISHABLE_LR = 10.0
#: Smallest noise level credited to a class, mm: below 0.1 um the model's
#: own approximations (second-order kinematics, linearised sensitivities)
#: are not trustworthy, so residuals that small are not evidence.
SIGMA_FLOOR = 1e-4
RSS_FLOOR = SIGMA_FLOOR ** 2
#: Weight of the prior on effect parameters, per prior magnitude: a total
#: value of a few typical magnitudes costs little, hundreds cost more than
#: any data can gain. Without it a linearised column that happens to carry
#: the noise (a depth scale scales the depth noise too) could "explain" the
#: noise by an absurd value.
PRIOR_WEIGHT = 0.3


def chi2_sf(x: float, k: int) -> float:
    """Upper tail of chi-square with k dof (scipy.special: no scipy.stats import)."""
    return float(chdtrc(k, x))
