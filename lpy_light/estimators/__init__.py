"""The estimators: how a chamber (and a plant in it) becomes tallies with their σ.

``registry`` names every estimator and its frozen settings; ``kernel_scene`` turns a chamber into the kernel's
records (:class:`~lpy_light.estimators.kernel_scene.KernelScene`: ``nee``, ``weighted``, ``analog``); ``memory``
checks the tallies fit; ``result`` is what every estimator returns (:class:`~lpy_light.estimators.result.Result`);
``reuse`` and ``field`` light a plant from the chamber's light stored once.  Imports the chamber and the kernel
only.
"""
