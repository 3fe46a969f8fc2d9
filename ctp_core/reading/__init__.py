"""Reading a prompt: the lexicon (``lexicon``, its data in ``lexicon.txt``), names in context (``context``), the
reading's passes (``passes.read``: relation, roles, ground, contents, name), copies (``counts``), default names
(``names``), the place on the ground the prompt names (``places``). The numbers of a prior are ``priors``'s."""
