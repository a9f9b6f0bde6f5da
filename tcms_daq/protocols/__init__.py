"""Protocol definitions shared by the drivers (the clients) and the simulators (the servers), so both speak
from one definition: the ND 287 frame, the AED reply format, the CiA 402 controlword/statusword and the drive's
EDS, the drive's Modbus register map. Pure definitions and codecs; neither ``drivers`` nor ``sim`` is imported.
"""
