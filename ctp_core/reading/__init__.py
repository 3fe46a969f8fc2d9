"""The words: everything the engine knows of a prompt before any geometry, torch-free (the service reads it).

The relations' records and their typed names (``records``: ``RelationName``, ``Kind``, ``RELATIONS``), their
wordings and how they are matched (``cues``), the relation a run uses (``relation.RelationReading``), the places a
prompt names and the parts' names (``places``: ``Place``, ``PartName``), the lexicon (``lexicon``, its data in
``lexicon.txt``), names in context (``context``), the prompt's passes (``passes.read_prompt``: relation, roles,
ground, contents, reading), copies (``counts``), default names (``names``) and a scene's description read by its
sentence structure (``scene.read_scene``: the relations said of each object). The numbers of a prior are
``priors``'s; the geometry of each relation and part is ``relations``', keyed by these names.
"""
