"""OPC UA: the axes' backlash, limit, state and TBE as a read-only OPC UA server
(asyncua 2.x).

Address space (namespace ``urn:mebm``)::

    Objects/Machines/<machine>/<axis>/BacklashMean             Double, µm (AnalogItemType, EngineeringUnits)
                                     /BacklashMeanUncertainty  Double, µm, expanded (k = 2)
                                     /BacklashLimit            Double, µm
                                     /State                    String: OK, WARNING, ALARM, UNKNOWN
                                     /Message                  String
                                     /MeasuredAt               DateTime
                                     /TBE/<task>               Double, µm (property Tolerance)
    Objects/Machines/<machine>/Notification/Prognoses/<axis>Backlash
                                     PredictedTime, Activity, Source   (OPC 40501-style)

docs/integration.md maps each node to its REST field. Values come from the service's
status (``api.service.status``), seeded at start and updated on each stored measurement,
failed cycle and alert change. No session may write.
"""

from api.opcua.server import OpcuaServer

__all__ = ["OpcuaServer"]
