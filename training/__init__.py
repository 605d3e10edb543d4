"""Training: PPO policies for the four tasks, and their export to ONNX.

The only package that imports torch and stable-baselines3. Everything downstream
(evaluation, optimisation, the host) runs the exported ONNX files with onnxruntime.
"""
