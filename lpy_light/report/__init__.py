"""Reports: figures (``plots``), SEC2's results read (``reference``) and the Angers validation against them
(``validation``).  Imports runs, the chamber and the estimators.
"""
