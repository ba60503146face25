"""app.line.opcua.space.reference_types_fixed: while a server's reference types stay as they
are, each one's subtypes are found once (asyncua walked the HasSubtype tree again for every
reference it browsed: most of the alarm conditions' instantiation at a server's start). The
same subtypes, so the same browse results, and asyncua's own walk back afterwards."""

from __future__ import annotations

import asyncio

from asyncua import Server, ua

from app.line.opcua.space import reference_types_fixed


def test_the_subtypes_found_once_are_asyncuas_and_its_walk_comes_back() -> None:
    async def scenario() -> None:
        server = Server()
        await server.init()
        view = server.iserver.view_service
        walked = {
            ref: set(view._get_sub_ref(ref))
            for ref in (
                ua.NodeId(ua.ObjectIds.References),
                ua.NodeId(ua.ObjectIds.HierarchicalReferences),
                ua.NodeId(ua.ObjectIds.HasChild),
                ua.NodeId(ua.ObjectIds.HasProperty),
            )
        }
        folder = server.nodes.objects
        browse = {"refs": ua.ObjectIds.HierarchicalReferences}
        children = await folder.get_references(**browse)
        with reference_types_fixed(server):
            for ref, subtypes in walked.items():
                assert set(view._get_sub_ref(ref)) == subtypes
                assert view._get_sub_ref(ref) is view._get_sub_ref(ref)  # found once
            assert await folder.get_references(**browse) == children
        assert walked[ua.NodeId(ua.ObjectIds.HasChild)]  # (a tree, not nothing)
        assert "_get_sub_ref" not in vars(view)  # asyncua's own walk again

    asyncio.run(scenario())
