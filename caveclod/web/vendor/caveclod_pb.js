/*eslint-disable block-scoped-var, id-length, no-control-regex, no-magic-numbers, no-mixed-operators, no-prototype-builtins, no-redeclare, no-shadow, no-var, sort-vars, default-case, jsdoc/require-param*/
(function($protobuf) {
    "use strict";

    var $Reader = $protobuf.Reader, $Writer = $protobuf.Writer, $util = $protobuf.util;
    var $Object = $util.global.Object, $undefined = $util.global.undefined, $Error = $util.global.Error, $RangeError = $util.global.RangeError;
    
    var $root = $protobuf.roots["default"] || ($protobuf.roots["default"] = {});
    
    $root.caveclod = (function() {
    
        var caveclod = {};
    
        caveclod.v1 = (function() {
    
            var v1 = {};
    
            v1.ClientMessage = (function() {
    
                var ClientMessage = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                ClientMessage.prototype.open = null;
                ClientMessage.prototype.pose = null;
                ClientMessage.prototype.ack = null;
                ClientMessage.prototype.keyframeRequest = null;
                ClientMessage.prototype.close = null;
    
                var $oneOfFields;
    
                $Object.defineProperty(ClientMessage.prototype, "kind", {
                    get: $util.oneOfGetter($oneOfFields = ["open", "pose", "ack", "keyframeRequest", "close"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                ClientMessage.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.open != null && $Object.hasOwnProperty.call(message, "open"))
                        $root.caveclod.v1.Open.encode(message.open, writer.uint32(10).fork(), _depth + 1).ldelim();
                    if (message.pose != null && $Object.hasOwnProperty.call(message, "pose"))
                        $root.caveclod.v1.CameraPose.encode(message.pose, writer.uint32(18).fork(), _depth + 1).ldelim();
                    if (message.ack != null && $Object.hasOwnProperty.call(message, "ack"))
                        $root.caveclod.v1.Ack.encode(message.ack, writer.uint32(26).fork(), _depth + 1).ldelim();
                    if (message.keyframeRequest != null && $Object.hasOwnProperty.call(message, "keyframeRequest"))
                        $root.caveclod.v1.KeyframeRequest.encode(message.keyframeRequest, writer.uint32(34).fork(), _depth + 1).ldelim();
                    if (message.close != null && $Object.hasOwnProperty.call(message, "close"))
                        $root.caveclod.v1.Close.encode(message.close, writer.uint32(42).fork(), _depth + 1).ldelim();
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                ClientMessage.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.ClientMessage();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 2)
                                    break;
                                message.open = $root.caveclod.v1.Open.decode(reader, reader.size(), $undefined, _depth + 1, message.open);
                                message.kind = "open";
                                continue;
                            }
                        case 2: {
                                if (wireType !== 2)
                                    break;
                                message.pose = $root.caveclod.v1.CameraPose.decode(reader, reader.size(), $undefined, _depth + 1, message.pose);
                                message.kind = "pose";
                                continue;
                            }
                        case 3: {
                                if (wireType !== 2)
                                    break;
                                message.ack = $root.caveclod.v1.Ack.decode(reader, reader.size(), $undefined, _depth + 1, message.ack);
                                message.kind = "ack";
                                continue;
                            }
                        case 4: {
                                if (wireType !== 2)
                                    break;
                                message.keyframeRequest = $root.caveclod.v1.KeyframeRequest.decode(reader, reader.size(), $undefined, _depth + 1, message.keyframeRequest);
                                message.kind = "keyframeRequest";
                                continue;
                            }
                        case 5: {
                                if (wireType !== 2)
                                    break;
                                message.close = $root.caveclod.v1.Close.decode(reader, reader.size(), $undefined, _depth + 1, message.close);
                                message.kind = "close";
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                ClientMessage.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.ClientMessage";
                };
    
                return ClientMessage;
            })();
    
            v1.Open = (function() {
    
                var Open = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                Open.prototype.mesh = "";
                Open.prototype.options = null;
                Open.prototype.cameras = 0;
                Open.prototype.vertexBufferHash = "";
                Open.prototype.resumeToken = "";
                Open.prototype.lastFrameSeq = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                Open.prototype.ackWindow = 0;
                Open.prototype.client = "";
                Open.prototype.cacheVertices = null;
                Open.prototype.cacheStrategy = 0;
                Open.prototype.cachePqFraction = null;
                Open.prototype.frameEncoding = 0;
                Open.prototype.vertexEncoding = 0;
                Open.prototype.positionBits = null;
                Open.prototype.morphTargets = false;
    
                var $oneOfFields;
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(Open.prototype, "_cacheVertices", {
                    get: $util.oneOfGetter($oneOfFields = ["cacheVertices"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(Open.prototype, "_cachePqFraction", {
                    get: $util.oneOfGetter($oneOfFields = ["cachePqFraction"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(Open.prototype, "_positionBits", {
                    get: $util.oneOfGetter($oneOfFields = ["positionBits"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                Open.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.mesh != null && $Object.hasOwnProperty.call(message, "mesh") && message.mesh !== "")
                        writer.uint32(10).string(message.mesh);
                    if (message.options != null && $Object.hasOwnProperty.call(message, "options"))
                        $root.caveclod.v1.RefineOptions.encode(message.options, writer.uint32(18).fork(), _depth + 1).ldelim();
                    if (message.cameras != null && $Object.hasOwnProperty.call(message, "cameras") && message.cameras !== 0)
                        writer.uint32(24).uint32(message.cameras);
                    if (message.vertexBufferHash != null && $Object.hasOwnProperty.call(message, "vertexBufferHash") && message.vertexBufferHash !== "")
                        writer.uint32(34).string(message.vertexBufferHash);
                    if (message.resumeToken != null && $Object.hasOwnProperty.call(message, "resumeToken") && message.resumeToken !== "")
                        writer.uint32(42).string(message.resumeToken);
                    if (message.lastFrameSeq != null && $Object.hasOwnProperty.call(message, "lastFrameSeq") && (typeof message.lastFrameSeq === "object" ? message.lastFrameSeq.low || message.lastFrameSeq.high : message.lastFrameSeq !== 0))
                        writer.uint32(48).uint64(message.lastFrameSeq);
                    if (message.ackWindow != null && $Object.hasOwnProperty.call(message, "ackWindow") && message.ackWindow !== 0)
                        writer.uint32(56).uint32(message.ackWindow);
                    if (message.client != null && $Object.hasOwnProperty.call(message, "client") && message.client !== "")
                        writer.uint32(66).string(message.client);
                    if (message.cacheVertices != null && $Object.hasOwnProperty.call(message, "cacheVertices"))
                        writer.uint32(72).uint32(message.cacheVertices);
                    if (message.cacheStrategy != null && $Object.hasOwnProperty.call(message, "cacheStrategy") && message.cacheStrategy !== 0)
                        writer.uint32(80).int32(message.cacheStrategy);
                    if (message.cachePqFraction != null && $Object.hasOwnProperty.call(message, "cachePqFraction"))
                        writer.uint32(89).double(message.cachePqFraction);
                    if (message.frameEncoding != null && $Object.hasOwnProperty.call(message, "frameEncoding") && message.frameEncoding !== 0)
                        writer.uint32(96).int32(message.frameEncoding);
                    if (message.vertexEncoding != null && $Object.hasOwnProperty.call(message, "vertexEncoding") && message.vertexEncoding !== 0)
                        writer.uint32(104).int32(message.vertexEncoding);
                    if (message.positionBits != null && $Object.hasOwnProperty.call(message, "positionBits"))
                        writer.uint32(112).uint32(message.positionBits);
                    if (message.morphTargets != null && $Object.hasOwnProperty.call(message, "morphTargets") && message.morphTargets !== false)
                        writer.uint32(120).bool(message.morphTargets);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                Open.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.Open();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.mesh = value;
                                else
                                    delete message.mesh;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 2)
                                    break;
                                message.options = $root.caveclod.v1.RefineOptions.decode(reader, reader.size(), $undefined, _depth + 1, message.options);
                                continue;
                            }
                        case 3: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.cameras = value;
                                else
                                    delete message.cameras;
                                continue;
                            }
                        case 4: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.vertexBufferHash = value;
                                else
                                    delete message.vertexBufferHash;
                                continue;
                            }
                        case 5: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.resumeToken = value;
                                else
                                    delete message.resumeToken;
                                continue;
                            }
                        case 6: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.lastFrameSeq = value;
                                else
                                    delete message.lastFrameSeq;
                                continue;
                            }
                        case 7: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.ackWindow = value;
                                else
                                    delete message.ackWindow;
                                continue;
                            }
                        case 8: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.client = value;
                                else
                                    delete message.client;
                                continue;
                            }
                        case 9: {
                                if (wireType !== 0)
                                    break;
                                message.cacheVertices = reader.uint32();
                                message._cacheVertices = "cacheVertices";
                                continue;
                            }
                        case 10: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.int32())
                                    message.cacheStrategy = value;
                                else
                                    delete message.cacheStrategy;
                                continue;
                            }
                        case 11: {
                                if (wireType !== 1)
                                    break;
                                message.cachePqFraction = reader.double();
                                message._cachePqFraction = "cachePqFraction";
                                continue;
                            }
                        case 12: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.int32())
                                    message.frameEncoding = value;
                                else
                                    delete message.frameEncoding;
                                continue;
                            }
                        case 13: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.int32())
                                    message.vertexEncoding = value;
                                else
                                    delete message.vertexEncoding;
                                continue;
                            }
                        case 14: {
                                if (wireType !== 0)
                                    break;
                                message.positionBits = reader.uint32();
                                message._positionBits = "positionBits";
                                continue;
                            }
                        case 15: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.bool())
                                    message.morphTargets = value;
                                else
                                    delete message.morphTargets;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                Open.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.Open";
                };
    
                return Open;
            })();
    
            v1.VertexEncoding = (function() {
                var valuesById = $Object.create(null), values = $Object.create(valuesById);
                values[valuesById[0] = "VERTEX_ENCODING_UNSPECIFIED"] = 0;
                values[valuesById[1] = "VERTEX_ENCODING_FLOAT32"] = 1;
                values[valuesById[2] = "VERTEX_ENCODING_PACKED"] = 2;
                return values;
            })();
    
            v1.FrameEncoding = (function() {
                var valuesById = $Object.create(null), values = $Object.create(valuesById);
                values[valuesById[0] = "FRAME_ENCODING_UNSPECIFIED"] = 0;
                values[valuesById[1] = "FRAME_ENCODING_RAW"] = 1;
                values[valuesById[2] = "FRAME_ENCODING_OPS"] = 2;
                values[valuesById[3] = "FRAME_ENCODING_OPS_LINKED"] = 3;
                return values;
            })();
    
            v1.CacheStrategy = (function() {
                var valuesById = $Object.create(null), values = $Object.create(valuesById);
                values[valuesById[0] = "CACHE_STRATEGY_UNSPECIFIED"] = 0;
                values[valuesById[1] = "CACHE_STRATEGY_FA"] = 1;
                values[valuesById[2] = "CACHE_STRATEGY_LRU"] = 2;
                values[valuesById[3] = "CACHE_STRATEGY_LRU_PQ"] = 3;
                return values;
            })();
    
            v1.RefineOptions = (function() {
    
                var RefineOptions = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                RefineOptions.prototype.viewportWidth = 0;
                RefineOptions.prototype.viewportHeight = 0;
                RefineOptions.prototype.fovYDeg = null;
                RefineOptions.prototype.tolerancePx = null;
                RefineOptions.prototype.cull = null;
                RefineOptions.prototype.backface = null;
                RefineOptions.prototype.maxOps = null;
                RefineOptions.prototype.maxFaces = null;
                RefineOptions.prototype.prune = null;
                RefineOptions.prototype.strictBound = null;
    
                var $oneOfFields;
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(RefineOptions.prototype, "_fovYDeg", {
                    get: $util.oneOfGetter($oneOfFields = ["fovYDeg"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(RefineOptions.prototype, "_tolerancePx", {
                    get: $util.oneOfGetter($oneOfFields = ["tolerancePx"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(RefineOptions.prototype, "_cull", {
                    get: $util.oneOfGetter($oneOfFields = ["cull"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(RefineOptions.prototype, "_backface", {
                    get: $util.oneOfGetter($oneOfFields = ["backface"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(RefineOptions.prototype, "_maxOps", {
                    get: $util.oneOfGetter($oneOfFields = ["maxOps"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(RefineOptions.prototype, "_maxFaces", {
                    get: $util.oneOfGetter($oneOfFields = ["maxFaces"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(RefineOptions.prototype, "_prune", {
                    get: $util.oneOfGetter($oneOfFields = ["prune"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(RefineOptions.prototype, "_strictBound", {
                    get: $util.oneOfGetter($oneOfFields = ["strictBound"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                RefineOptions.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.viewportWidth != null && $Object.hasOwnProperty.call(message, "viewportWidth") && message.viewportWidth !== 0)
                        writer.uint32(8).uint32(message.viewportWidth);
                    if (message.viewportHeight != null && $Object.hasOwnProperty.call(message, "viewportHeight") && message.viewportHeight !== 0)
                        writer.uint32(16).uint32(message.viewportHeight);
                    if (message.fovYDeg != null && $Object.hasOwnProperty.call(message, "fovYDeg"))
                        writer.uint32(25).double(message.fovYDeg);
                    if (message.tolerancePx != null && $Object.hasOwnProperty.call(message, "tolerancePx"))
                        writer.uint32(33).double(message.tolerancePx);
                    if (message.cull != null && $Object.hasOwnProperty.call(message, "cull"))
                        writer.uint32(40).bool(message.cull);
                    if (message.backface != null && $Object.hasOwnProperty.call(message, "backface"))
                        writer.uint32(48).bool(message.backface);
                    if (message.maxOps != null && $Object.hasOwnProperty.call(message, "maxOps"))
                        writer.uint32(56).uint64(message.maxOps);
                    if (message.maxFaces != null && $Object.hasOwnProperty.call(message, "maxFaces"))
                        writer.uint32(64).uint64(message.maxFaces);
                    if (message.prune != null && $Object.hasOwnProperty.call(message, "prune"))
                        writer.uint32(72).bool(message.prune);
                    if (message.strictBound != null && $Object.hasOwnProperty.call(message, "strictBound"))
                        writer.uint32(80).bool(message.strictBound);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                RefineOptions.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.RefineOptions();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.viewportWidth = value;
                                else
                                    delete message.viewportWidth;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.viewportHeight = value;
                                else
                                    delete message.viewportHeight;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 1)
                                    break;
                                message.fovYDeg = reader.double();
                                message._fovYDeg = "fovYDeg";
                                continue;
                            }
                        case 4: {
                                if (wireType !== 1)
                                    break;
                                message.tolerancePx = reader.double();
                                message._tolerancePx = "tolerancePx";
                                continue;
                            }
                        case 5: {
                                if (wireType !== 0)
                                    break;
                                message.cull = reader.bool();
                                message._cull = "cull";
                                continue;
                            }
                        case 6: {
                                if (wireType !== 0)
                                    break;
                                message.backface = reader.bool();
                                message._backface = "backface";
                                continue;
                            }
                        case 7: {
                                if (wireType !== 0)
                                    break;
                                message.maxOps = reader.uint64();
                                message._maxOps = "maxOps";
                                continue;
                            }
                        case 8: {
                                if (wireType !== 0)
                                    break;
                                message.maxFaces = reader.uint64();
                                message._maxFaces = "maxFaces";
                                continue;
                            }
                        case 9: {
                                if (wireType !== 0)
                                    break;
                                message.prune = reader.bool();
                                message._prune = "prune";
                                continue;
                            }
                        case 10: {
                                if (wireType !== 0)
                                    break;
                                message.strictBound = reader.bool();
                                message._strictBound = "strictBound";
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                RefineOptions.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.RefineOptions";
                };
    
                return RefineOptions;
            })();
    
            v1.CameraPose = (function() {
    
                var CameraPose = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                CameraPose.prototype.camera = 0;
                CameraPose.prototype.poseSeq = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                CameraPose.prototype.eye = null;
                CameraPose.prototype.target = null;
                CameraPose.prototype.up = null;
                CameraPose.prototype.ackFrameSeq = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
    
                CameraPose.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.camera != null && $Object.hasOwnProperty.call(message, "camera") && message.camera !== 0)
                        writer.uint32(8).uint32(message.camera);
                    if (message.poseSeq != null && $Object.hasOwnProperty.call(message, "poseSeq") && (typeof message.poseSeq === "object" ? message.poseSeq.low || message.poseSeq.high : message.poseSeq !== 0))
                        writer.uint32(16).uint64(message.poseSeq);
                    if (message.eye != null && $Object.hasOwnProperty.call(message, "eye"))
                        $root.caveclod.v1.Vec3.encode(message.eye, writer.uint32(26).fork(), _depth + 1).ldelim();
                    if (message.target != null && $Object.hasOwnProperty.call(message, "target"))
                        $root.caveclod.v1.Vec3.encode(message.target, writer.uint32(34).fork(), _depth + 1).ldelim();
                    if (message.up != null && $Object.hasOwnProperty.call(message, "up"))
                        $root.caveclod.v1.Vec3.encode(message.up, writer.uint32(42).fork(), _depth + 1).ldelim();
                    if (message.ackFrameSeq != null && $Object.hasOwnProperty.call(message, "ackFrameSeq") && (typeof message.ackFrameSeq === "object" ? message.ackFrameSeq.low || message.ackFrameSeq.high : message.ackFrameSeq !== 0))
                        writer.uint32(48).uint64(message.ackFrameSeq);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                CameraPose.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.CameraPose();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.camera = value;
                                else
                                    delete message.camera;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.poseSeq = value;
                                else
                                    delete message.poseSeq;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 2)
                                    break;
                                message.eye = $root.caveclod.v1.Vec3.decode(reader, reader.size(), $undefined, _depth + 1, message.eye);
                                continue;
                            }
                        case 4: {
                                if (wireType !== 2)
                                    break;
                                message.target = $root.caveclod.v1.Vec3.decode(reader, reader.size(), $undefined, _depth + 1, message.target);
                                continue;
                            }
                        case 5: {
                                if (wireType !== 2)
                                    break;
                                message.up = $root.caveclod.v1.Vec3.decode(reader, reader.size(), $undefined, _depth + 1, message.up);
                                continue;
                            }
                        case 6: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.ackFrameSeq = value;
                                else
                                    delete message.ackFrameSeq;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                CameraPose.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.CameraPose";
                };
    
                return CameraPose;
            })();
    
            v1.Ack = (function() {
    
                var Ack = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                Ack.prototype.frameSeq = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
    
                Ack.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.frameSeq != null && $Object.hasOwnProperty.call(message, "frameSeq") && (typeof message.frameSeq === "object" ? message.frameSeq.low || message.frameSeq.high : message.frameSeq !== 0))
                        writer.uint32(8).uint64(message.frameSeq);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                Ack.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.Ack();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.frameSeq = value;
                                else
                                    delete message.frameSeq;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                Ack.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.Ack";
                };
    
                return Ack;
            })();
    
            v1.KeyframeRequest = (function() {
    
                var KeyframeRequest = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                KeyframeRequest.prototype.camera = null;
                KeyframeRequest.prototype.reason = 0;
                KeyframeRequest.prototype.frameSeq = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                KeyframeRequest.prototype.detail = "";
    
                var $oneOfFields;
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(KeyframeRequest.prototype, "_camera", {
                    get: $util.oneOfGetter($oneOfFields = ["camera"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                KeyframeRequest.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.camera != null && $Object.hasOwnProperty.call(message, "camera"))
                        writer.uint32(8).uint32(message.camera);
                    if (message.reason != null && $Object.hasOwnProperty.call(message, "reason") && message.reason !== 0)
                        writer.uint32(16).int32(message.reason);
                    if (message.frameSeq != null && $Object.hasOwnProperty.call(message, "frameSeq") && (typeof message.frameSeq === "object" ? message.frameSeq.low || message.frameSeq.high : message.frameSeq !== 0))
                        writer.uint32(24).uint64(message.frameSeq);
                    if (message.detail != null && $Object.hasOwnProperty.call(message, "detail") && message.detail !== "")
                        writer.uint32(34).string(message.detail);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                KeyframeRequest.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.KeyframeRequest();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                message.camera = reader.uint32();
                                message._camera = "camera";
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.int32())
                                    message.reason = value;
                                else
                                    delete message.reason;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.frameSeq = value;
                                else
                                    delete message.frameSeq;
                                continue;
                            }
                        case 4: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.detail = value;
                                else
                                    delete message.detail;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                KeyframeRequest.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.KeyframeRequest";
                };
    
                return KeyframeRequest;
            })();
    
            v1.KeyframeReason = (function() {
                var valuesById = $Object.create(null), values = $Object.create(valuesById);
                values[valuesById[0] = "KEYFRAME_REASON_UNSPECIFIED"] = 0;
                values[valuesById[1] = "KEYFRAME_REASON_CHECKSUM_MISMATCH"] = 1;
                values[valuesById[2] = "KEYFRAME_REASON_BAD_FRAME"] = 2;
                values[valuesById[3] = "KEYFRAME_REASON_CLIENT_RESET"] = 3;
                return values;
            })();
    
            v1.Close = (function() {
    
                var Close = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                Close.prototype.reason = "";
    
                Close.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.reason != null && $Object.hasOwnProperty.call(message, "reason") && message.reason !== "")
                        writer.uint32(10).string(message.reason);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                Close.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.Close();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.reason = value;
                                else
                                    delete message.reason;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                Close.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.Close";
                };
    
                return Close;
            })();
    
            v1.ServerMessage = (function() {
    
                var ServerMessage = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                ServerMessage.prototype.sessionInfo = null;
                ServerMessage.prototype.vertexChunk = null;
                ServerMessage.prototype.frame = null;
                ServerMessage.prototype.status = null;
    
                var $oneOfFields;
    
                $Object.defineProperty(ServerMessage.prototype, "kind", {
                    get: $util.oneOfGetter($oneOfFields = ["sessionInfo", "vertexChunk", "frame", "status"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                ServerMessage.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.sessionInfo != null && $Object.hasOwnProperty.call(message, "sessionInfo"))
                        $root.caveclod.v1.SessionInfo.encode(message.sessionInfo, writer.uint32(10).fork(), _depth + 1).ldelim();
                    if (message.vertexChunk != null && $Object.hasOwnProperty.call(message, "vertexChunk"))
                        $root.caveclod.v1.VertexChunk.encode(message.vertexChunk, writer.uint32(18).fork(), _depth + 1).ldelim();
                    if (message.frame != null && $Object.hasOwnProperty.call(message, "frame"))
                        $root.caveclod.v1.Frame.encode(message.frame, writer.uint32(26).fork(), _depth + 1).ldelim();
                    if (message.status != null && $Object.hasOwnProperty.call(message, "status"))
                        $root.caveclod.v1.Status.encode(message.status, writer.uint32(34).fork(), _depth + 1).ldelim();
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                ServerMessage.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.ServerMessage();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 2)
                                    break;
                                message.sessionInfo = $root.caveclod.v1.SessionInfo.decode(reader, reader.size(), $undefined, _depth + 1, message.sessionInfo);
                                message.kind = "sessionInfo";
                                continue;
                            }
                        case 2: {
                                if (wireType !== 2)
                                    break;
                                message.vertexChunk = $root.caveclod.v1.VertexChunk.decode(reader, reader.size(), $undefined, _depth + 1, message.vertexChunk);
                                message.kind = "vertexChunk";
                                continue;
                            }
                        case 3: {
                                if (wireType !== 2)
                                    break;
                                message.frame = $root.caveclod.v1.Frame.decode(reader, reader.size(), $undefined, _depth + 1, message.frame);
                                message.kind = "frame";
                                continue;
                            }
                        case 4: {
                                if (wireType !== 2)
                                    break;
                                message.status = $root.caveclod.v1.Status.decode(reader, reader.size(), $undefined, _depth + 1, message.status);
                                message.kind = "status";
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                ServerMessage.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.ServerMessage";
                };
    
                return ServerMessage;
            })();
    
            v1.Status = (function() {
    
                var Status = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                Status.prototype.code = 0;
                Status.prototype.message = "";
    
                Status.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.code != null && $Object.hasOwnProperty.call(message, "code") && message.code !== 0)
                        writer.uint32(8).uint32(message.code);
                    if (message.message != null && $Object.hasOwnProperty.call(message, "message") && message.message !== "")
                        writer.uint32(18).string(message.message);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                Status.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.Status();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.code = value;
                                else
                                    delete message.code;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.message = value;
                                else
                                    delete message.message;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                Status.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.Status";
                };
    
                return Status;
            })();
    
            v1.SessionInfo = (function() {
    
                var SessionInfo = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                SessionInfo.prototype.sessionToken = "";
                SessionInfo.prototype.resumed = false;
                SessionInfo.prototype.mesh = null;
                SessionInfo.prototype.vertexFormat = null;
                SessionInfo.prototype.vertexBufferCached = false;
                SessionInfo.prototype.vertexPayloadCrc32 = 0;
                SessionInfo.prototype.options = null;
                SessionInfo.prototype.cameras = 0;
                SessionInfo.prototype.ackWindow = 0;
                SessionInfo.prototype.resumeTtlS = 0;
                SessionInfo.prototype.lastFrameSeq = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                SessionInfo.prototype.lastPoseSeq = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                SessionInfo.prototype.maxChunkBytes = 0;
                SessionInfo.prototype.cacheVertices = 0;
                SessionInfo.prototype.cacheStrategy = 0;
                SessionInfo.prototype.cachePqFraction = 0;
                SessionInfo.prototype.frameEncoding = 0;
                SessionInfo.prototype.acksOnPoses = false;
                SessionInfo.prototype.vertexPacking = null;
    
                SessionInfo.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.sessionToken != null && $Object.hasOwnProperty.call(message, "sessionToken") && message.sessionToken !== "")
                        writer.uint32(10).string(message.sessionToken);
                    if (message.resumed != null && $Object.hasOwnProperty.call(message, "resumed") && message.resumed !== false)
                        writer.uint32(16).bool(message.resumed);
                    if (message.mesh != null && $Object.hasOwnProperty.call(message, "mesh"))
                        $root.caveclod.v1.MeshInfo.encode(message.mesh, writer.uint32(26).fork(), _depth + 1).ldelim();
                    if (message.vertexFormat != null && $Object.hasOwnProperty.call(message, "vertexFormat"))
                        $root.caveclod.v1.VertexFormat.encode(message.vertexFormat, writer.uint32(34).fork(), _depth + 1).ldelim();
                    if (message.vertexBufferCached != null && $Object.hasOwnProperty.call(message, "vertexBufferCached") && message.vertexBufferCached !== false)
                        writer.uint32(40).bool(message.vertexBufferCached);
                    if (message.vertexPayloadCrc32 != null && $Object.hasOwnProperty.call(message, "vertexPayloadCrc32") && message.vertexPayloadCrc32 !== 0)
                        writer.uint32(53).fixed32(message.vertexPayloadCrc32);
                    if (message.options != null && $Object.hasOwnProperty.call(message, "options"))
                        $root.caveclod.v1.RefineOptions.encode(message.options, writer.uint32(58).fork(), _depth + 1).ldelim();
                    if (message.cameras != null && $Object.hasOwnProperty.call(message, "cameras") && message.cameras !== 0)
                        writer.uint32(64).uint32(message.cameras);
                    if (message.ackWindow != null && $Object.hasOwnProperty.call(message, "ackWindow") && message.ackWindow !== 0)
                        writer.uint32(72).uint32(message.ackWindow);
                    if (message.resumeTtlS != null && $Object.hasOwnProperty.call(message, "resumeTtlS") && message.resumeTtlS !== 0)
                        writer.uint32(80).uint32(message.resumeTtlS);
                    if (message.lastFrameSeq != null && $Object.hasOwnProperty.call(message, "lastFrameSeq") && (typeof message.lastFrameSeq === "object" ? message.lastFrameSeq.low || message.lastFrameSeq.high : message.lastFrameSeq !== 0))
                        writer.uint32(88).uint64(message.lastFrameSeq);
                    if (message.lastPoseSeq != null && $Object.hasOwnProperty.call(message, "lastPoseSeq") && (typeof message.lastPoseSeq === "object" ? message.lastPoseSeq.low || message.lastPoseSeq.high : message.lastPoseSeq !== 0))
                        writer.uint32(96).uint64(message.lastPoseSeq);
                    if (message.maxChunkBytes != null && $Object.hasOwnProperty.call(message, "maxChunkBytes") && message.maxChunkBytes !== 0)
                        writer.uint32(104).uint32(message.maxChunkBytes);
                    if (message.cacheVertices != null && $Object.hasOwnProperty.call(message, "cacheVertices") && message.cacheVertices !== 0)
                        writer.uint32(112).uint32(message.cacheVertices);
                    if (message.cacheStrategy != null && $Object.hasOwnProperty.call(message, "cacheStrategy") && message.cacheStrategy !== 0)
                        writer.uint32(120).int32(message.cacheStrategy);
                    if (message.cachePqFraction != null && $Object.hasOwnProperty.call(message, "cachePqFraction") && !$Object.is(message.cachePqFraction, 0))
                        writer.uint32(129).double(message.cachePqFraction);
                    if (message.frameEncoding != null && $Object.hasOwnProperty.call(message, "frameEncoding") && message.frameEncoding !== 0)
                        writer.uint32(136).int32(message.frameEncoding);
                    if (message.acksOnPoses != null && $Object.hasOwnProperty.call(message, "acksOnPoses") && message.acksOnPoses !== false)
                        writer.uint32(144).bool(message.acksOnPoses);
                    if (message.vertexPacking != null && $Object.hasOwnProperty.call(message, "vertexPacking"))
                        $root.caveclod.v1.VertexPacking.encode(message.vertexPacking, writer.uint32(154).fork(), _depth + 1).ldelim();
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                SessionInfo.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.SessionInfo();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.sessionToken = value;
                                else
                                    delete message.sessionToken;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.bool())
                                    message.resumed = value;
                                else
                                    delete message.resumed;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 2)
                                    break;
                                message.mesh = $root.caveclod.v1.MeshInfo.decode(reader, reader.size(), $undefined, _depth + 1, message.mesh);
                                continue;
                            }
                        case 4: {
                                if (wireType !== 2)
                                    break;
                                message.vertexFormat = $root.caveclod.v1.VertexFormat.decode(reader, reader.size(), $undefined, _depth + 1, message.vertexFormat);
                                continue;
                            }
                        case 5: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.bool())
                                    message.vertexBufferCached = value;
                                else
                                    delete message.vertexBufferCached;
                                continue;
                            }
                        case 6: {
                                if (wireType !== 5)
                                    break;
                                if (value = reader.fixed32())
                                    message.vertexPayloadCrc32 = value;
                                else
                                    delete message.vertexPayloadCrc32;
                                continue;
                            }
                        case 7: {
                                if (wireType !== 2)
                                    break;
                                message.options = $root.caveclod.v1.RefineOptions.decode(reader, reader.size(), $undefined, _depth + 1, message.options);
                                continue;
                            }
                        case 8: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.cameras = value;
                                else
                                    delete message.cameras;
                                continue;
                            }
                        case 9: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.ackWindow = value;
                                else
                                    delete message.ackWindow;
                                continue;
                            }
                        case 10: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.resumeTtlS = value;
                                else
                                    delete message.resumeTtlS;
                                continue;
                            }
                        case 11: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.lastFrameSeq = value;
                                else
                                    delete message.lastFrameSeq;
                                continue;
                            }
                        case 12: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.lastPoseSeq = value;
                                else
                                    delete message.lastPoseSeq;
                                continue;
                            }
                        case 13: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.maxChunkBytes = value;
                                else
                                    delete message.maxChunkBytes;
                                continue;
                            }
                        case 14: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.cacheVertices = value;
                                else
                                    delete message.cacheVertices;
                                continue;
                            }
                        case 15: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.int32())
                                    message.cacheStrategy = value;
                                else
                                    delete message.cacheStrategy;
                                continue;
                            }
                        case 16: {
                                if (wireType !== 1)
                                    break;
                                if (!$Object.is(value = reader.double(), 0))
                                    message.cachePqFraction = value;
                                else
                                    delete message.cachePqFraction;
                                continue;
                            }
                        case 17: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.int32())
                                    message.frameEncoding = value;
                                else
                                    delete message.frameEncoding;
                                continue;
                            }
                        case 18: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.bool())
                                    message.acksOnPoses = value;
                                else
                                    delete message.acksOnPoses;
                                continue;
                            }
                        case 19: {
                                if (wireType !== 2)
                                    break;
                                message.vertexPacking = $root.caveclod.v1.VertexPacking.decode(reader, reader.size(), $undefined, _depth + 1, message.vertexPacking);
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                SessionInfo.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.SessionInfo";
                };
    
                return SessionInfo;
            })();
    
            v1.VertexPacking = (function() {
    
                var VertexPacking = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                VertexPacking.prototype.encoding = 0;
                VertexPacking.prototype.packedBytes = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                VertexPacking.prototype.packedCrc32 = 0;
                VertexPacking.prototype.vertexBufferHash = "";
                VertexPacking.prototype.positionBits = 0;
                VertexPacking.prototype.positionOrigin = null;
                VertexPacking.prototype.positionStep = 0;
                VertexPacking.prototype.normalBits = 0;
                VertexPacking.prototype.texcoordStep = 0;
                VertexPacking.prototype.maxPositionError = 0;
                VertexPacking.prototype.maxNormalDegrees = 0;
    
                VertexPacking.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.encoding != null && $Object.hasOwnProperty.call(message, "encoding") && message.encoding !== 0)
                        writer.uint32(8).int32(message.encoding);
                    if (message.packedBytes != null && $Object.hasOwnProperty.call(message, "packedBytes") && (typeof message.packedBytes === "object" ? message.packedBytes.low || message.packedBytes.high : message.packedBytes !== 0))
                        writer.uint32(16).uint64(message.packedBytes);
                    if (message.packedCrc32 != null && $Object.hasOwnProperty.call(message, "packedCrc32") && message.packedCrc32 !== 0)
                        writer.uint32(29).fixed32(message.packedCrc32);
                    if (message.vertexBufferHash != null && $Object.hasOwnProperty.call(message, "vertexBufferHash") && message.vertexBufferHash !== "")
                        writer.uint32(34).string(message.vertexBufferHash);
                    if (message.positionBits != null && $Object.hasOwnProperty.call(message, "positionBits") && message.positionBits !== 0)
                        writer.uint32(40).uint32(message.positionBits);
                    if (message.positionOrigin != null && $Object.hasOwnProperty.call(message, "positionOrigin"))
                        $root.caveclod.v1.Vec3.encode(message.positionOrigin, writer.uint32(50).fork(), _depth + 1).ldelim();
                    if (message.positionStep != null && $Object.hasOwnProperty.call(message, "positionStep") && !$Object.is(message.positionStep, 0))
                        writer.uint32(57).double(message.positionStep);
                    if (message.normalBits != null && $Object.hasOwnProperty.call(message, "normalBits") && message.normalBits !== 0)
                        writer.uint32(64).uint32(message.normalBits);
                    if (message.texcoordStep != null && $Object.hasOwnProperty.call(message, "texcoordStep") && !$Object.is(message.texcoordStep, 0))
                        writer.uint32(73).double(message.texcoordStep);
                    if (message.maxPositionError != null && $Object.hasOwnProperty.call(message, "maxPositionError") && !$Object.is(message.maxPositionError, 0))
                        writer.uint32(81).double(message.maxPositionError);
                    if (message.maxNormalDegrees != null && $Object.hasOwnProperty.call(message, "maxNormalDegrees") && !$Object.is(message.maxNormalDegrees, 0))
                        writer.uint32(89).double(message.maxNormalDegrees);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                VertexPacking.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.VertexPacking();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.int32())
                                    message.encoding = value;
                                else
                                    delete message.encoding;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.packedBytes = value;
                                else
                                    delete message.packedBytes;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 5)
                                    break;
                                if (value = reader.fixed32())
                                    message.packedCrc32 = value;
                                else
                                    delete message.packedCrc32;
                                continue;
                            }
                        case 4: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.vertexBufferHash = value;
                                else
                                    delete message.vertexBufferHash;
                                continue;
                            }
                        case 5: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.positionBits = value;
                                else
                                    delete message.positionBits;
                                continue;
                            }
                        case 6: {
                                if (wireType !== 2)
                                    break;
                                message.positionOrigin = $root.caveclod.v1.Vec3.decode(reader, reader.size(), $undefined, _depth + 1, message.positionOrigin);
                                continue;
                            }
                        case 7: {
                                if (wireType !== 1)
                                    break;
                                if (!$Object.is(value = reader.double(), 0))
                                    message.positionStep = value;
                                else
                                    delete message.positionStep;
                                continue;
                            }
                        case 8: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.normalBits = value;
                                else
                                    delete message.normalBits;
                                continue;
                            }
                        case 9: {
                                if (wireType !== 1)
                                    break;
                                if (!$Object.is(value = reader.double(), 0))
                                    message.texcoordStep = value;
                                else
                                    delete message.texcoordStep;
                                continue;
                            }
                        case 10: {
                                if (wireType !== 1)
                                    break;
                                if (!$Object.is(value = reader.double(), 0))
                                    message.maxPositionError = value;
                                else
                                    delete message.maxPositionError;
                                continue;
                            }
                        case 11: {
                                if (wireType !== 1)
                                    break;
                                if (!$Object.is(value = reader.double(), 0))
                                    message.maxNormalDegrees = value;
                                else
                                    delete message.maxNormalDegrees;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                VertexPacking.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.VertexPacking";
                };
    
                return VertexPacking;
            })();
    
            v1.MeshInfo = (function() {
    
                var MeshInfo = function (properties) {
                    this.materials = [];
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                MeshInfo.prototype.name = "";
                MeshInfo.prototype.faces = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                MeshInfo.prototype.vertices = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                MeshInfo.prototype.positions = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                MeshInfo.prototype.nodes = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                MeshInfo.prototype.baseFaces = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                MeshInfo.prototype.surfaceGroupIds = 0;
                MeshInfo.prototype.materials = $util.emptyArray;
                MeshInfo.prototype.boundsMin = null;
                MeshInfo.prototype.boundsMax = null;
                MeshInfo.prototype.contentHash = "";
                MeshInfo.prototype.vertexBufferHash = "";
                MeshInfo.prototype.origin = null;
    
                MeshInfo.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.name != null && $Object.hasOwnProperty.call(message, "name") && message.name !== "")
                        writer.uint32(10).string(message.name);
                    if (message.faces != null && $Object.hasOwnProperty.call(message, "faces") && (typeof message.faces === "object" ? message.faces.low || message.faces.high : message.faces !== 0))
                        writer.uint32(16).uint64(message.faces);
                    if (message.vertices != null && $Object.hasOwnProperty.call(message, "vertices") && (typeof message.vertices === "object" ? message.vertices.low || message.vertices.high : message.vertices !== 0))
                        writer.uint32(24).uint64(message.vertices);
                    if (message.positions != null && $Object.hasOwnProperty.call(message, "positions") && (typeof message.positions === "object" ? message.positions.low || message.positions.high : message.positions !== 0))
                        writer.uint32(32).uint64(message.positions);
                    if (message.nodes != null && $Object.hasOwnProperty.call(message, "nodes") && (typeof message.nodes === "object" ? message.nodes.low || message.nodes.high : message.nodes !== 0))
                        writer.uint32(40).uint64(message.nodes);
                    if (message.baseFaces != null && $Object.hasOwnProperty.call(message, "baseFaces") && (typeof message.baseFaces === "object" ? message.baseFaces.low || message.baseFaces.high : message.baseFaces !== 0))
                        writer.uint32(48).uint64(message.baseFaces);
                    if (message.surfaceGroupIds != null && $Object.hasOwnProperty.call(message, "surfaceGroupIds") && message.surfaceGroupIds !== 0)
                        writer.uint32(56).uint32(message.surfaceGroupIds);
                    if (message.materials != null && message.materials.length)
                        for (var i = 0; i < message.materials.length; ++i)
                            $root.caveclod.v1.Material.encode(message.materials[i], writer.uint32(66).fork(), _depth + 1).ldelim();
                    if (message.boundsMin != null && $Object.hasOwnProperty.call(message, "boundsMin"))
                        $root.caveclod.v1.Vec3.encode(message.boundsMin, writer.uint32(74).fork(), _depth + 1).ldelim();
                    if (message.boundsMax != null && $Object.hasOwnProperty.call(message, "boundsMax"))
                        $root.caveclod.v1.Vec3.encode(message.boundsMax, writer.uint32(82).fork(), _depth + 1).ldelim();
                    if (message.contentHash != null && $Object.hasOwnProperty.call(message, "contentHash") && message.contentHash !== "")
                        writer.uint32(90).string(message.contentHash);
                    if (message.vertexBufferHash != null && $Object.hasOwnProperty.call(message, "vertexBufferHash") && message.vertexBufferHash !== "")
                        writer.uint32(98).string(message.vertexBufferHash);
                    if (message.origin != null && $Object.hasOwnProperty.call(message, "origin"))
                        $root.caveclod.v1.Vec3.encode(message.origin, writer.uint32(106).fork(), _depth + 1).ldelim();
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                MeshInfo.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.MeshInfo();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.name = value;
                                else
                                    delete message.name;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.faces = value;
                                else
                                    delete message.faces;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.vertices = value;
                                else
                                    delete message.vertices;
                                continue;
                            }
                        case 4: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.positions = value;
                                else
                                    delete message.positions;
                                continue;
                            }
                        case 5: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.nodes = value;
                                else
                                    delete message.nodes;
                                continue;
                            }
                        case 6: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.baseFaces = value;
                                else
                                    delete message.baseFaces;
                                continue;
                            }
                        case 7: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.surfaceGroupIds = value;
                                else
                                    delete message.surfaceGroupIds;
                                continue;
                            }
                        case 8: {
                                if (wireType !== 2)
                                    break;
                                if (!(message.materials && message.materials.length))
                                    message.materials = [];
                                message.materials.push($root.caveclod.v1.Material.decode(reader, reader.size(), $undefined, _depth + 1));
                                continue;
                            }
                        case 9: {
                                if (wireType !== 2)
                                    break;
                                message.boundsMin = $root.caveclod.v1.Vec3.decode(reader, reader.size(), $undefined, _depth + 1, message.boundsMin);
                                continue;
                            }
                        case 10: {
                                if (wireType !== 2)
                                    break;
                                message.boundsMax = $root.caveclod.v1.Vec3.decode(reader, reader.size(), $undefined, _depth + 1, message.boundsMax);
                                continue;
                            }
                        case 11: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.contentHash = value;
                                else
                                    delete message.contentHash;
                                continue;
                            }
                        case 12: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.vertexBufferHash = value;
                                else
                                    delete message.vertexBufferHash;
                                continue;
                            }
                        case 13: {
                                if (wireType !== 2)
                                    break;
                                message.origin = $root.caveclod.v1.Vec3.decode(reader, reader.size(), $undefined, _depth + 1, message.origin);
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                MeshInfo.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.MeshInfo";
                };
    
                return MeshInfo;
            })();
    
            v1.Material = (function() {
    
                var Material = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                Material.prototype.id = 0;
                Material.prototype.name = "";
    
                Material.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.id != null && $Object.hasOwnProperty.call(message, "id") && message.id !== 0)
                        writer.uint32(8).uint32(message.id);
                    if (message.name != null && $Object.hasOwnProperty.call(message, "name") && message.name !== "")
                        writer.uint32(18).string(message.name);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                Material.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.Material();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.id = value;
                                else
                                    delete message.id;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.stringVerify()).length)
                                    message.name = value;
                                else
                                    delete message.name;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                Material.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.Material";
                };
    
                return Material;
            })();
    
            v1.VertexFormat = (function() {
    
                var VertexFormat = function (properties) {
                    this.attributes = [];
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                VertexFormat.prototype.layout = 0;
                VertexFormat.prototype.vertexCount = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                VertexFormat.prototype.payloadBytes = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                VertexFormat.prototype.attributes = $util.emptyArray;
    
                VertexFormat.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.layout != null && $Object.hasOwnProperty.call(message, "layout") && message.layout !== 0)
                        writer.uint32(8).int32(message.layout);
                    if (message.vertexCount != null && $Object.hasOwnProperty.call(message, "vertexCount") && (typeof message.vertexCount === "object" ? message.vertexCount.low || message.vertexCount.high : message.vertexCount !== 0))
                        writer.uint32(16).uint64(message.vertexCount);
                    if (message.payloadBytes != null && $Object.hasOwnProperty.call(message, "payloadBytes") && (typeof message.payloadBytes === "object" ? message.payloadBytes.low || message.payloadBytes.high : message.payloadBytes !== 0))
                        writer.uint32(24).uint64(message.payloadBytes);
                    if (message.attributes != null && message.attributes.length)
                        for (var i = 0; i < message.attributes.length; ++i)
                            $root.caveclod.v1.VertexAttribute.encode(message.attributes[i], writer.uint32(34).fork(), _depth + 1).ldelim();
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                VertexFormat.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.VertexFormat();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.int32())
                                    message.layout = value;
                                else
                                    delete message.layout;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.vertexCount = value;
                                else
                                    delete message.vertexCount;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.payloadBytes = value;
                                else
                                    delete message.payloadBytes;
                                continue;
                            }
                        case 4: {
                                if (wireType !== 2)
                                    break;
                                if (!(message.attributes && message.attributes.length))
                                    message.attributes = [];
                                message.attributes.push($root.caveclod.v1.VertexAttribute.decode(reader, reader.size(), $undefined, _depth + 1));
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                VertexFormat.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.VertexFormat";
                };
    
                return VertexFormat;
            })();
    
            v1.VertexAttribute = (function() {
    
                var VertexAttribute = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                VertexAttribute.prototype.semantic = 0;
                VertexAttribute.prototype.type = 0;
                VertexAttribute.prototype.components = 0;
                VertexAttribute.prototype.normalized = false;
                VertexAttribute.prototype.offset = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                VertexAttribute.prototype.stride = 0;
    
                VertexAttribute.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.semantic != null && $Object.hasOwnProperty.call(message, "semantic") && message.semantic !== 0)
                        writer.uint32(8).int32(message.semantic);
                    if (message.type != null && $Object.hasOwnProperty.call(message, "type") && message.type !== 0)
                        writer.uint32(16).int32(message.type);
                    if (message.components != null && $Object.hasOwnProperty.call(message, "components") && message.components !== 0)
                        writer.uint32(24).uint32(message.components);
                    if (message.normalized != null && $Object.hasOwnProperty.call(message, "normalized") && message.normalized !== false)
                        writer.uint32(32).bool(message.normalized);
                    if (message.offset != null && $Object.hasOwnProperty.call(message, "offset") && (typeof message.offset === "object" ? message.offset.low || message.offset.high : message.offset !== 0))
                        writer.uint32(40).uint64(message.offset);
                    if (message.stride != null && $Object.hasOwnProperty.call(message, "stride") && message.stride !== 0)
                        writer.uint32(48).uint32(message.stride);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                VertexAttribute.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.VertexAttribute();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.int32())
                                    message.semantic = value;
                                else
                                    delete message.semantic;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.int32())
                                    message.type = value;
                                else
                                    delete message.type;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.components = value;
                                else
                                    delete message.components;
                                continue;
                            }
                        case 4: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.bool())
                                    message.normalized = value;
                                else
                                    delete message.normalized;
                                continue;
                            }
                        case 5: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.offset = value;
                                else
                                    delete message.offset;
                                continue;
                            }
                        case 6: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.stride = value;
                                else
                                    delete message.stride;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                VertexAttribute.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.VertexAttribute";
                };
    
                return VertexAttribute;
            })();
    
            v1.VertexLayout = (function() {
                var valuesById = $Object.create(null), values = $Object.create(valuesById);
                values[valuesById[0] = "VERTEX_LAYOUT_UNSPECIFIED"] = 0;
                values[valuesById[1] = "VERTEX_LAYOUT_PLANAR"] = 1;
                values[valuesById[2] = "VERTEX_LAYOUT_INTERLEAVED"] = 2;
                return values;
            })();
    
            v1.AttributeSemantic = (function() {
                var valuesById = $Object.create(null), values = $Object.create(valuesById);
                values[valuesById[0] = "ATTRIBUTE_SEMANTIC_UNSPECIFIED"] = 0;
                values[valuesById[1] = "ATTRIBUTE_SEMANTIC_POSITION"] = 1;
                values[valuesById[2] = "ATTRIBUTE_SEMANTIC_NORMAL"] = 2;
                values[valuesById[3] = "ATTRIBUTE_SEMANTIC_TEXCOORD"] = 3;
                values[valuesById[4] = "ATTRIBUTE_SEMANTIC_COLOR"] = 4;
                values[valuesById[5] = "ATTRIBUTE_SEMANTIC_MORPH_TARGET"] = 5;
                return values;
            })();
    
            v1.ScalarType = (function() {
                var valuesById = $Object.create(null), values = $Object.create(valuesById);
                values[valuesById[0] = "SCALAR_TYPE_UNSPECIFIED"] = 0;
                values[valuesById[1] = "SCALAR_TYPE_FLOAT32"] = 1;
                values[valuesById[2] = "SCALAR_TYPE_UINT8"] = 2;
                values[valuesById[3] = "SCALAR_TYPE_UINT32"] = 3;
                return values;
            })();
    
            v1.VertexChunk = (function() {
    
                var VertexChunk = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                VertexChunk.prototype.offset = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                VertexChunk.prototype.total = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                VertexChunk.prototype.data = $util.newBuffer([]);
    
                VertexChunk.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.offset != null && $Object.hasOwnProperty.call(message, "offset") && (typeof message.offset === "object" ? message.offset.low || message.offset.high : message.offset !== 0))
                        writer.uint32(8).uint64(message.offset);
                    if (message.total != null && $Object.hasOwnProperty.call(message, "total") && (typeof message.total === "object" ? message.total.low || message.total.high : message.total !== 0))
                        writer.uint32(16).uint64(message.total);
                    if (message.data != null && $Object.hasOwnProperty.call(message, "data") && message.data.length)
                        writer.uint32(26).bytes(message.data);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                VertexChunk.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.VertexChunk();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.offset = value;
                                else
                                    delete message.offset;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.total = value;
                                else
                                    delete message.total;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.bytes()).length)
                                    message.data = value;
                                else
                                    delete message.data;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                VertexChunk.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.VertexChunk";
                };
    
                return VertexChunk;
            })();
    
            v1.Frame = (function() {
    
                var Frame = function (properties) {
                    this.cameras = [];
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                Frame.prototype.frameSeq = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                Frame.prototype.poseSeq = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                Frame.prototype.cameras = $util.emptyArray;
                Frame.prototype.continued = false;
                Frame.prototype.posesSuperseded = 0;
    
                Frame.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.frameSeq != null && $Object.hasOwnProperty.call(message, "frameSeq") && (typeof message.frameSeq === "object" ? message.frameSeq.low || message.frameSeq.high : message.frameSeq !== 0))
                        writer.uint32(8).uint64(message.frameSeq);
                    if (message.poseSeq != null && $Object.hasOwnProperty.call(message, "poseSeq") && (typeof message.poseSeq === "object" ? message.poseSeq.low || message.poseSeq.high : message.poseSeq !== 0))
                        writer.uint32(16).uint64(message.poseSeq);
                    if (message.cameras != null && message.cameras.length)
                        for (var i = 0; i < message.cameras.length; ++i)
                            $root.caveclod.v1.CameraFrame.encode(message.cameras[i], writer.uint32(26).fork(), _depth + 1).ldelim();
                    if (message.continued != null && $Object.hasOwnProperty.call(message, "continued") && message.continued !== false)
                        writer.uint32(32).bool(message.continued);
                    if (message.posesSuperseded != null && $Object.hasOwnProperty.call(message, "posesSuperseded") && message.posesSuperseded !== 0)
                        writer.uint32(40).uint32(message.posesSuperseded);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                Frame.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.Frame();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.frameSeq = value;
                                else
                                    delete message.frameSeq;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.poseSeq = value;
                                else
                                    delete message.poseSeq;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 2)
                                    break;
                                if (!(message.cameras && message.cameras.length))
                                    message.cameras = [];
                                message.cameras.push($root.caveclod.v1.CameraFrame.decode(reader, reader.size(), $undefined, _depth + 1));
                                continue;
                            }
                        case 4: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.bool())
                                    message.continued = value;
                                else
                                    delete message.continued;
                                continue;
                            }
                        case 5: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.posesSuperseded = value;
                                else
                                    delete message.posesSuperseded;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                Frame.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.Frame";
                };
    
                return Frame;
            })();
    
            v1.CameraFrame = (function() {
    
                var CameraFrame = function (properties) {
                    this.surfaces = [];
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                CameraFrame.prototype.camera = 0;
                CameraFrame.prototype.poseSeq = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                CameraFrame.prototype.keyframe = false;
                CameraFrame.prototype.surfaces = $util.emptyArray;
                CameraFrame.prototype.stats = null;
                CameraFrame.prototype.vertices = null;
    
                CameraFrame.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.camera != null && $Object.hasOwnProperty.call(message, "camera") && message.camera !== 0)
                        writer.uint32(8).uint32(message.camera);
                    if (message.poseSeq != null && $Object.hasOwnProperty.call(message, "poseSeq") && (typeof message.poseSeq === "object" ? message.poseSeq.low || message.poseSeq.high : message.poseSeq !== 0))
                        writer.uint32(16).uint64(message.poseSeq);
                    if (message.keyframe != null && $Object.hasOwnProperty.call(message, "keyframe") && message.keyframe !== false)
                        writer.uint32(24).bool(message.keyframe);
                    if (message.surfaces != null && message.surfaces.length)
                        for (var i = 0; i < message.surfaces.length; ++i)
                            $root.caveclod.v1.SurfaceDelta.encode(message.surfaces[i], writer.uint32(34).fork(), _depth + 1).ldelim();
                    if (message.stats != null && $Object.hasOwnProperty.call(message, "stats"))
                        $root.caveclod.v1.CameraStats.encode(message.stats, writer.uint32(42).fork(), _depth + 1).ldelim();
                    if (message.vertices != null && $Object.hasOwnProperty.call(message, "vertices"))
                        $root.caveclod.v1.VertexWrites.encode(message.vertices, writer.uint32(50).fork(), _depth + 1).ldelim();
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                CameraFrame.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.CameraFrame();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.camera = value;
                                else
                                    delete message.camera;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.poseSeq = value;
                                else
                                    delete message.poseSeq;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.bool())
                                    message.keyframe = value;
                                else
                                    delete message.keyframe;
                                continue;
                            }
                        case 4: {
                                if (wireType !== 2)
                                    break;
                                if (!(message.surfaces && message.surfaces.length))
                                    message.surfaces = [];
                                message.surfaces.push($root.caveclod.v1.SurfaceDelta.decode(reader, reader.size(), $undefined, _depth + 1));
                                continue;
                            }
                        case 5: {
                                if (wireType !== 2)
                                    break;
                                message.stats = $root.caveclod.v1.CameraStats.decode(reader, reader.size(), $undefined, _depth + 1, message.stats);
                                continue;
                            }
                        case 6: {
                                if (wireType !== 2)
                                    break;
                                message.vertices = $root.caveclod.v1.VertexWrites.decode(reader, reader.size(), $undefined, _depth + 1, message.vertices);
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                CameraFrame.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.CameraFrame";
                };
    
                return CameraFrame;
            })();
    
            v1.VertexWrites = (function() {
    
                var VertexWrites = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                VertexWrites.prototype.slots = $util.newBuffer([]);
                VertexWrites.prototype.firstSlot = 0;
                VertexWrites.prototype.data = $util.newBuffer([]);
                VertexWrites.prototype.slotsChecksum = 0;
    
                VertexWrites.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.slots != null && $Object.hasOwnProperty.call(message, "slots") && message.slots.length)
                        writer.uint32(10).bytes(message.slots);
                    if (message.firstSlot != null && $Object.hasOwnProperty.call(message, "firstSlot") && message.firstSlot !== 0)
                        writer.uint32(16).uint32(message.firstSlot);
                    if (message.data != null && $Object.hasOwnProperty.call(message, "data") && message.data.length)
                        writer.uint32(26).bytes(message.data);
                    if (message.slotsChecksum != null && $Object.hasOwnProperty.call(message, "slotsChecksum") && message.slotsChecksum !== 0)
                        writer.uint32(37).fixed32(message.slotsChecksum);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                VertexWrites.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.VertexWrites();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.bytes()).length)
                                    message.slots = value;
                                else
                                    delete message.slots;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.firstSlot = value;
                                else
                                    delete message.firstSlot;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.bytes()).length)
                                    message.data = value;
                                else
                                    delete message.data;
                                continue;
                            }
                        case 4: {
                                if (wireType !== 5)
                                    break;
                                if (value = reader.fixed32())
                                    message.slotsChecksum = value;
                                else
                                    delete message.slotsChecksum;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                VertexWrites.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.VertexWrites";
                };
    
                return VertexWrites;
            })();
    
            v1.SurfaceDelta = (function() {
    
                var SurfaceDelta = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                SurfaceDelta.prototype.material = 0;
                SurfaceDelta.prototype.count = 0;
                SurfaceDelta.prototype.slots = $util.newBuffer([]);
                SurfaceDelta.prototype.firstSlot = 0;
                SurfaceDelta.prototype.tris = $util.newBuffer([]);
                SurfaceDelta.prototype.crc32 = null;
                SurfaceDelta.prototype.ops = $util.newBuffer([]);
    
                var $oneOfFields;
    
                // Virtual OneOf for proto3 optional field
                $Object.defineProperty(SurfaceDelta.prototype, "_crc32", {
                    get: $util.oneOfGetter($oneOfFields = ["crc32"]),
                    set: $util.oneOfSetter($oneOfFields)
                });
    
                SurfaceDelta.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.material != null && $Object.hasOwnProperty.call(message, "material") && message.material !== 0)
                        writer.uint32(8).uint32(message.material);
                    if (message.count != null && $Object.hasOwnProperty.call(message, "count") && message.count !== 0)
                        writer.uint32(16).uint32(message.count);
                    if (message.slots != null && $Object.hasOwnProperty.call(message, "slots") && message.slots.length)
                        writer.uint32(26).bytes(message.slots);
                    if (message.firstSlot != null && $Object.hasOwnProperty.call(message, "firstSlot") && message.firstSlot !== 0)
                        writer.uint32(32).uint32(message.firstSlot);
                    if (message.tris != null && $Object.hasOwnProperty.call(message, "tris") && message.tris.length)
                        writer.uint32(42).bytes(message.tris);
                    if (message.crc32 != null && $Object.hasOwnProperty.call(message, "crc32"))
                        writer.uint32(53).fixed32(message.crc32);
                    if (message.ops != null && $Object.hasOwnProperty.call(message, "ops") && message.ops.length)
                        writer.uint32(58).bytes(message.ops);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                SurfaceDelta.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.SurfaceDelta();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.material = value;
                                else
                                    delete message.material;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.count = value;
                                else
                                    delete message.count;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.bytes()).length)
                                    message.slots = value;
                                else
                                    delete message.slots;
                                continue;
                            }
                        case 4: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.firstSlot = value;
                                else
                                    delete message.firstSlot;
                                continue;
                            }
                        case 5: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.bytes()).length)
                                    message.tris = value;
                                else
                                    delete message.tris;
                                continue;
                            }
                        case 6: {
                                if (wireType !== 5)
                                    break;
                                message.crc32 = reader.fixed32();
                                message._crc32 = "crc32";
                                continue;
                            }
                        case 7: {
                                if (wireType !== 2)
                                    break;
                                if ((value = reader.bytes()).length)
                                    message.ops = value;
                                else
                                    delete message.ops;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                SurfaceDelta.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.SurfaceDelta";
                };
    
                return SurfaceDelta;
            })();
    
            v1.CameraStats = (function() {
    
                var CameraStats = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                CameraStats.prototype.splits = 0;
                CameraStats.prototype.collapses = 0;
                CameraStats.prototype.updateUs = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                CameraStats.prototype.activeFaces = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                CameraStats.prototype.budgetExhausted = false;
                CameraStats.prototype.poseAgeUs = $util.Long ? $util.Long.fromBits(0,0,true) : 0;
                CameraStats.prototype.cacheHits = 0;
                CameraStats.prototype.cacheInserts = 0;
                CameraStats.prototype.cacheTolerancePx = 0;
                CameraStats.prototype.updates = 0;
                CameraStats.prototype.hiddenParts = 0;
    
                CameraStats.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.splits != null && $Object.hasOwnProperty.call(message, "splits") && message.splits !== 0)
                        writer.uint32(8).uint32(message.splits);
                    if (message.collapses != null && $Object.hasOwnProperty.call(message, "collapses") && message.collapses !== 0)
                        writer.uint32(16).uint32(message.collapses);
                    if (message.updateUs != null && $Object.hasOwnProperty.call(message, "updateUs") && (typeof message.updateUs === "object" ? message.updateUs.low || message.updateUs.high : message.updateUs !== 0))
                        writer.uint32(24).uint64(message.updateUs);
                    if (message.activeFaces != null && $Object.hasOwnProperty.call(message, "activeFaces") && (typeof message.activeFaces === "object" ? message.activeFaces.low || message.activeFaces.high : message.activeFaces !== 0))
                        writer.uint32(32).uint64(message.activeFaces);
                    if (message.budgetExhausted != null && $Object.hasOwnProperty.call(message, "budgetExhausted") && message.budgetExhausted !== false)
                        writer.uint32(40).bool(message.budgetExhausted);
                    if (message.poseAgeUs != null && $Object.hasOwnProperty.call(message, "poseAgeUs") && (typeof message.poseAgeUs === "object" ? message.poseAgeUs.low || message.poseAgeUs.high : message.poseAgeUs !== 0))
                        writer.uint32(48).uint64(message.poseAgeUs);
                    if (message.cacheHits != null && $Object.hasOwnProperty.call(message, "cacheHits") && message.cacheHits !== 0)
                        writer.uint32(56).uint32(message.cacheHits);
                    if (message.cacheInserts != null && $Object.hasOwnProperty.call(message, "cacheInserts") && message.cacheInserts !== 0)
                        writer.uint32(64).uint32(message.cacheInserts);
                    if (message.cacheTolerancePx != null && $Object.hasOwnProperty.call(message, "cacheTolerancePx") && !$Object.is(message.cacheTolerancePx, 0))
                        writer.uint32(73).double(message.cacheTolerancePx);
                    if (message.updates != null && $Object.hasOwnProperty.call(message, "updates") && message.updates !== 0)
                        writer.uint32(80).uint32(message.updates);
                    if (message.hiddenParts != null && $Object.hasOwnProperty.call(message, "hiddenParts") && message.hiddenParts !== 0)
                        writer.uint32(88).uint32(message.hiddenParts);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                CameraStats.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.CameraStats();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.splits = value;
                                else
                                    delete message.splits;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.collapses = value;
                                else
                                    delete message.collapses;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.updateUs = value;
                                else
                                    delete message.updateUs;
                                continue;
                            }
                        case 4: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.activeFaces = value;
                                else
                                    delete message.activeFaces;
                                continue;
                            }
                        case 5: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.bool())
                                    message.budgetExhausted = value;
                                else
                                    delete message.budgetExhausted;
                                continue;
                            }
                        case 6: {
                                if (wireType !== 0)
                                    break;
                                if (typeof (value = reader.uint64()) === "object" ? value.low || value.high : value !== 0)
                                    message.poseAgeUs = value;
                                else
                                    delete message.poseAgeUs;
                                continue;
                            }
                        case 7: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.cacheHits = value;
                                else
                                    delete message.cacheHits;
                                continue;
                            }
                        case 8: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.cacheInserts = value;
                                else
                                    delete message.cacheInserts;
                                continue;
                            }
                        case 9: {
                                if (wireType !== 1)
                                    break;
                                if (!$Object.is(value = reader.double(), 0))
                                    message.cacheTolerancePx = value;
                                else
                                    delete message.cacheTolerancePx;
                                continue;
                            }
                        case 10: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.updates = value;
                                else
                                    delete message.updates;
                                continue;
                            }
                        case 11: {
                                if (wireType !== 0)
                                    break;
                                if (value = reader.uint32())
                                    message.hiddenParts = value;
                                else
                                    delete message.hiddenParts;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                CameraStats.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.CameraStats";
                };
    
                return CameraStats;
            })();
    
            v1.Vec3 = (function() {
    
                var Vec3 = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                Vec3.prototype.x = 0;
                Vec3.prototype.y = 0;
                Vec3.prototype.z = 0;
    
                Vec3.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.x != null && $Object.hasOwnProperty.call(message, "x") && !$Object.is(message.x, 0))
                        writer.uint32(9).double(message.x);
                    if (message.y != null && $Object.hasOwnProperty.call(message, "y") && !$Object.is(message.y, 0))
                        writer.uint32(17).double(message.y);
                    if (message.z != null && $Object.hasOwnProperty.call(message, "z") && !$Object.is(message.z, 0))
                        writer.uint32(25).double(message.z);
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                Vec3.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message, value;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.Vec3();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 1)
                                    break;
                                if (!$Object.is(value = reader.double(), 0))
                                    message.x = value;
                                else
                                    delete message.x;
                                continue;
                            }
                        case 2: {
                                if (wireType !== 1)
                                    break;
                                if (!$Object.is(value = reader.double(), 0))
                                    message.y = value;
                                else
                                    delete message.y;
                                continue;
                            }
                        case 3: {
                                if (wireType !== 1)
                                    break;
                                if (!$Object.is(value = reader.double(), 0))
                                    message.z = value;
                                else
                                    delete message.z;
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                Vec3.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.Vec3";
                };
    
                return Vec3;
            })();
    
            v1.ListMeshesRequest = (function() {
    
                var ListMeshesRequest = function (properties) {
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                ListMeshesRequest.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                ListMeshesRequest.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.ListMeshesRequest();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        reader.skipType(tag & 7, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                ListMeshesRequest.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.ListMeshesRequest";
                };
    
                return ListMeshesRequest;
            })();
    
            v1.ListMeshesResponse = (function() {
    
                var ListMeshesResponse = function (properties) {
                    this.meshes = [];
                    if (properties)
                        for (var keys = $Object.keys(properties), i = 0; i < keys.length; ++i)
                            if (properties[keys[i]] != null && keys[i] !== "__proto__")
                                this[keys[i]] = properties[keys[i]];
                };
    
                ListMeshesResponse.prototype.meshes = $util.emptyArray;
    
                ListMeshesResponse.encode = function (message, writer, _depth) {
                    if (!writer)
                        writer = $Writer.create();
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $util.recursionLimit)
                        throw $Error("max depth exceeded");
                    if (message.meshes != null && message.meshes.length)
                        for (var i = 0; i < message.meshes.length; ++i)
                            $root.caveclod.v1.MeshInfo.encode(message.meshes[i], writer.uint32(10).fork(), _depth + 1).ldelim();
                    if (message.$unknowns != null && $Object.hasOwnProperty.call(message, "$unknowns"))
                        for (var i = 0; i < message.$unknowns.length; ++i)
                            writer.raw(message.$unknowns[i]);
                    return writer;
                };
    
                ListMeshesResponse.decode = function (reader, length, _end, _depth, _target) {
                    if (!(reader instanceof $Reader))
                        reader = $Reader.create(reader);
                    if (_depth === $undefined)
                        _depth = 0;
                    if (_depth > $Reader.recursionLimit)
                        throw $Error("max depth exceeded");
                    var end, message;
                    if (length === $undefined)
                        end = reader.len;
                    else {
                        end = reader.pos + length;
                        if (end > reader.len)
                            throw $RangeError("index out of range");
                        length = reader.len;
                        reader.len = end;
                    }
                    message = _target || new $root.caveclod.v1.ListMeshesResponse();
                    while (reader.pos < end) {
                        var start = reader.pos;
                        var tag = reader.tag();
                        if (tag === _end) {
                            _end = $undefined;
                            break;
                        }
                        var wireType = tag & 7;
                        switch (tag >>>= 3) {
                        case 1: {
                                if (wireType !== 2)
                                    break;
                                if (!(message.meshes && message.meshes.length))
                                    message.meshes = [];
                                message.meshes.push($root.caveclod.v1.MeshInfo.decode(reader, reader.size(), $undefined, _depth + 1));
                                continue;
                            }
                        }
                        reader.skipType(wireType, _depth, tag);
                        if (!reader.discardUnknown) {
                            $util.makeProp(message, "$unknowns", false);
                            (message.$unknowns || (message.$unknowns = [])).push(reader.raw(start, reader.pos));
                        }
                    }
                    if (length !== $undefined) {
                        if (reader.pos !== end)
                            throw $RangeError("index out of range");
                        reader.len = length;
                    }
                    if (_end !== $undefined)
                        throw $Error("missing end group");
                    return message;
                };
    
                ListMeshesResponse.getTypeUrl = function(prefix) {
                    if (prefix === $undefined)
                        prefix = "type.googleapis.com";
                    return prefix + "/caveclod.v1.ListMeshesResponse";
                };
    
                return ListMeshesResponse;
            })();
    
            return v1;
        })();
    
        return caveclod;
    })();

    return $root;
})(protobuf);
