"""The bundled policies: ``TASK.onnx`` with its model card ``TASK.json`` and learning
curve ``TASK.png`` for each task, trained on the project's 2-core machines (see each
model card for steps, wall time and evaluation results)."""
