"""The guide: the vision-language model that scores renders against the prompt or a picture.

``selection`` (which model a run uses: ``auto``, torch-free), ``checkpoints`` (whether a model's weights are on
this machine, torch-free), ``store`` (the local model cache), ``loaders`` (specs to loaded guides), ``guidance``
(the guide's encoders and scores), ``runtime`` (torch or ONNX Runtime for forward-only encoding), ``goals`` (what
the guide compares renders with: a text, a picture, per-view references) and ``upright`` (the upright judge).

Nothing is imported here: the service imports the torch-free modules without loading torch.
"""
