"""The gonioreflectometer's motor controllers over serial: ``ptu`` (:mod:`.ptu`) and ``indexer`` (:mod:`.indexer`).

Both are :class:`~sbrdf_lib.serial.controller.MotorController` drivers; :mod:`.sim` serves each one's protocol
on a pseudo-terminal for tests and ``port: sim``.
"""
