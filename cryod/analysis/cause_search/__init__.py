"""The search for the causes of what the simulation gets wrong on a record: its steps, rules and results.

:func:`cryod.analysis.pipeline.analyze` runs the steps in order:

1. replay the record and measure the noise, 2. recalibrate the base model, 3. rank the candidates
   (:mod:`~cryod.analysis.cause_search.first_round`);
4. follow paths of causes from the leading candidates, refitted jointly with the recalibration
   (:mod:`~cryod.analysis.cause_search.path_choice`, :mod:`~cryod.analysis.cause_search.path`,
   :mod:`~cryod.analysis.cause_search.joint_refit`, :mod:`~cryod.analysis.cause_search.unneeded_causes`);
5. read the causes named the other way round (:mod:`~cryod.analysis.cause_search.path_choice`);
6. judge (:mod:`~cryod.analysis.cause_search.verdict`, with
   :mod:`~cryod.analysis.cause_search.generic_judgement`);
7. ask whether the base model is further off than the recalibration allows
   (:mod:`~cryod.analysis.cause_search.base_model_off`);
8. describe what is left (:mod:`~cryod.analysis.cause_search.what_is_left`).

Every step takes and returns frozen dataclasses (:mod:`~cryod.analysis.cause_search.results`, or the step's own
module for what only the next step reads); what every step shares is a
:class:`~cryod.analysis.cause_search.record_search.RecordSearch`. Each rule the steps apply is one predicate of
:mod:`~cryod.analysis.cause_search.rules`, whose docstring says what it decides and why.
"""
