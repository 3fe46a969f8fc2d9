"""The relations a prompt names, as the geometry knows them: the records and their wordings (``vocabulary``,
torch-free: the reader and the service read it), one spec per relation (``spec``, ``registry.SPECS``) defined by
the kind modules (``resting``, ``contained``, ``attached``, ``apart``), what their judges share (``measures``) and
their builders share (``building``), the ground's parts the usual places are on (``parts``), the judging API
(``predicates``) and the search's use of the builders (``builders``). docs/relations.md says each relation's
definition and usual place.

Nothing is imported here: importing ``relations.vocabulary`` must not load torch.
"""
